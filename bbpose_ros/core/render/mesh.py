# Copyright 2026 bbpose_ros developers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.

"""A triangle mesh in the form the renderers draw: float32 arrays, colours and normals."""

from dataclasses import dataclass
from typing import Self

import numpy as np
import numpy.typing as npt

from bbpose_ros.core.data.models import convex_hull_points, ObjectModel
from bbpose_ros.core.util.errors import InputError


@dataclass(frozen=True)
class RenderMesh:
    """
    A coloured triangle mesh in its model frame.

    Attributes:
        vertices: (V, 3) float32 positions, metres.
        faces: (F, 3) uint32 vertex indices.
        colors: (V, 3) float32 RGB in [0, 1].
        normals: (V, 3) float32 unit vertex normals (area-weighted face normals).
        hull_points: (H, 3) float64 convex-hull vertices, for fast amodal boxes.

    """

    vertices: np.ndarray
    faces: np.ndarray
    colors: np.ndarray
    normals: np.ndarray
    hull_points: np.ndarray

    @classmethod
    def from_arrays(cls, vertices: npt.ArrayLike, faces: npt.ArrayLike,
                    colors_uint8: npt.ArrayLike, hull_points: npt.ArrayLike | None = None
                    ) -> Self:
        """
        Build from (V, 3) vertices in metres, (F, 3) faces and (V, 3) uint8 RGB colours.

        Normals are computed here; the hull too unless given.
        """
        vertices = np.asarray(vertices, dtype=np.float64)
        faces = np.asarray(faces)
        colors_uint8 = np.asarray(colors_uint8)
        if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) < 3:
            raise InputError(f'mesh vertices must be (V, 3), got {vertices.shape}')
        if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
            raise InputError(f'mesh faces must be (F, 3), got {faces.shape}')
        if faces.min() < 0 or faces.max() >= len(vertices):
            raise InputError('mesh faces index vertices that do not exist')
        if colors_uint8.shape != vertices.shape:
            raise InputError(f'mesh colours must be (V, 3) like the vertices, got '
                             f'{colors_uint8.shape}')
        if hull_points is None:
            hull_points = convex_hull_points(vertices)
        return cls(vertices=vertices.astype(np.float32), faces=faces.astype(np.uint32),
                   colors=colors_uint8.astype(np.float32) / 255.0,
                   normals=vertex_normals(vertices, faces).astype(np.float32),
                   hull_points=np.asarray(hull_points, dtype=np.float64))

    @classmethod
    def from_object_model(cls, model: ObjectModel) -> Self:
        """Build from a ``bbpose_ros.core.data.models.ObjectModel`` (reusing its hull)."""
        return cls.from_arrays(model.vertices, model.faces, model.vertex_colors,
                               model.hull_points)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(V, 3) unit vertex normals: the area-weighted sum of the adjacent face normals."""
    corners = vertices[faces]
    face_normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals = np.zeros_like(vertices, dtype=np.float64)
    for k in range(3):
        np.add.at(normals, faces[:, k], face_normals)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.where(length > 0.0, normals / np.maximum(length, 1e-30), [0.0, 0.0, 1.0])
