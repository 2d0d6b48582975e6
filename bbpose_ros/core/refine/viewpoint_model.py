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

"""
Sparse viewpoint models: the mesh's silhouette contour seen from many directions.

As in SRT3D (Stoiber et al. 2022), the refiner never renders while it optimises: for a few
hundred to a few thousand view directions on a geodesic sphere around the object, this
module stores points of the silhouette contour in the model frame, their outward normals
(perpendicular to the view direction) and how far the silhouette continues on either side.
At run time the view closest to the current camera direction supplies the correspondence
lines.

Silhouettes are drawn without OpenGL: the contour-generator edges of the mesh (between a
face turned towards the camera and one turned away, plus open boundary edges) enclose the
silhouette, so drawing them as lines and flood-filling the outside from the image border
gives the silhouette at the cost of a few OpenCV calls, whatever the number of triangles.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import hashlib
from pathlib import Path
import zipfile
import zlib

import cv2
import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from bbpose_ros.core.refine import contour_projection
from bbpose_ros.core.util.errors import InputError

# The template camera: at TEMPLATE_DISTANCE_M from the model origin, the diameter spans
# TEMPLATE_DIAMETER_PX pixels (sub-pixel contours; cost grows with the square of it).
TEMPLATE_DISTANCE_M = 0.8
TEMPLATE_DIAMETER_PX = 240.0
_SUBPIXEL_BITS = 4
_TANGENT_STEP = 3           # contour neighbours on either side that define a tangent
CACHE_FORMAT = 1


@dataclass(frozen=True)
class ViewpointModel:
    """
    Contour points of one object seen from many directions, in the model frame (metres).

    Arrays other than ``view_directions`` are float32 (the cache's precision).

    Attributes:
        view_directions: (V, 3) unit vectors from the model origin towards the camera.
        points: (V, P, 3) contour points of each view.
        normals: (V, P, 3) unit outward contour normals, perpendicular to the view direction.
        foreground_m: (V, P) how far the silhouette continues inwards along -normal.
        background_m: (V, P) how far the background continues outwards along +normal before
            the silhouette comes back (capped at the diameter).
        diameter: object diameter, metres.

    """

    view_directions: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    foreground_m: np.ndarray
    background_m: np.ndarray
    diameter: float

    def closest_views(self, rotations: npt.ArrayLike, translations: npt.ArrayLike
                      ) -> np.ndarray:
        """
        Per pose, the index of the stored view nearest to the camera's direction.

        Args:
            rotations: (N, 3, 3) model-to-camera rotations.
            translations: (N, 3) translations (any unit).

        Returns:
            (N,) int view indices.

        """
        return contour_projection.closest_views(
            np.ascontiguousarray(self.view_directions, dtype=float),
            np.ascontiguousarray(rotations, dtype=float).reshape(-1, 3, 3),
            np.ascontiguousarray(translations, dtype=float).reshape(-1, 3))

    def save(self, path: Path | str) -> None:
        """Write the model to ``path`` in .npz format, whatever its suffix."""
        with open(path, 'wb') as stream:
            self._save(stream)

    def _save(self, stream):
        np.savez(stream, format=CACHE_FORMAT, view_directions=self.view_directions,
                 points=self.points, normals=self.normals, foreground_m=self.foreground_m,
                 background_m=self.background_m, diameter=self.diameter)

    @classmethod
    def load(cls, path: Path | str) -> ViewpointModel:
        """Read a model written by ``save``; InputError when the file is not one."""
        try:
            with np.load(path) as data:
                if int(data['format']) != CACHE_FORMAT:
                    raise InputError(f'{path}: viewpoint model format {int(data["format"])}, '
                                     f'expected {CACHE_FORMAT}')
                return cls(data['view_directions'], data['points'], data['normals'],
                           data['foreground_m'], data['background_m'], float(data['diameter']))
        except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile,
                zlib.error) as err:
            raise InputError(f'{path}: not a viewpoint model ({err})') from err


def geodesic_directions(subdivisions: int) -> np.ndarray:
    """
    (V, 3) unit vectors on an icosphere: 12, 42, 162, 642, 2562 ... for 0, 1, 2, 3, 4 ...

    Neighbouring directions are about 63 / 2**subdivisions degrees apart.
    """
    phi = (1.0 + 5.0 ** 0.5) / 2.0
    vertices = [(-1, phi, 0), (1, phi, 0), (-1, -phi, 0), (1, -phi, 0), (0, -1, phi),
                (0, 1, phi), (0, -1, -phi), (0, 1, -phi), (phi, 0, -1), (phi, 0, 1),
                (-phi, 0, -1), (-phi, 0, 1)]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
             (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
             (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    points = [np.array(v, dtype=float) / np.linalg.norm(v) for v in vertices]
    for _ in range(subdivisions):
        midpoint = {}

        def middle(a, b):
            key = (min(a, b), max(a, b))
            if key not in midpoint:
                m = points[a] + points[b]
                points.append(m / np.linalg.norm(m))
                midpoint[key] = len(points) - 1
            return midpoint[key]

        new_faces = []
        for a, b, c in faces:
            ab, bc, ca = middle(a, b), middle(b, c), middle(c, a)
            new_faces += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new_faces
    return np.stack(points)


def look_at_rotation(direction: npt.ArrayLike) -> np.ndarray:
    """(3, 3) model-to-camera rotation of a camera on ``direction`` looking at the origin."""
    z_axis = -np.asarray(direction, dtype=float)
    z_axis = z_axis / np.linalg.norm(z_axis)
    helper = np.array([0.0, 0.0, 1.0]) if abs(z_axis[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x_axis = np.cross(helper, z_axis)
    x_axis /= np.linalg.norm(x_axis)
    return np.stack([x_axis, np.cross(z_axis, x_axis), z_axis])


class _EdgeTable:
    """The mesh's unique edges with the (up to two) faces on either side."""

    def __init__(self, vertices, faces):
        self.vertices = np.asarray(vertices, dtype=float)
        faces = np.asarray(faces, dtype=np.int64)
        corners = self.vertices[faces]
        normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        self.face_normals = normals
        self.face_offsets = np.einsum('ij,ij->i', normals, corners[:, 0])
        edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
        owner = np.tile(np.arange(len(faces)), 3)
        edges = np.sort(edges, axis=1)
        order = np.lexsort((edges[:, 1], edges[:, 0]))
        edges, owner = edges[order], owner[order]
        first = np.ones(len(edges), dtype=bool)
        first[1:] = np.any(edges[1:] != edges[:-1], axis=1)
        starts = np.flatnonzero(first)
        self.edges = edges[starts]
        self.face_a = owner[starts]
        counts = np.diff(np.append(starts, len(edges)))
        self.face_b = np.where(counts >= 2, owner[np.minimum(starts + 1, len(owner) - 1)], -1)

    def contour_edges(self, camera_position):
        """(E, 2) vertex indices of the edges that can bound the silhouette from there."""
        facing = self.face_normals @ camera_position - self.face_offsets > 0.0
        side_a = facing[self.face_a]
        side_b = np.where(self.face_b >= 0, facing[np.maximum(self.face_b, 0)], ~side_a)
        return self.edges[side_a != side_b]


def _silhouette(uv_edges, size):
    """(size, size) bool silhouette enclosed by the (E, 2, 2) projected edges."""
    canvas = np.zeros((size + 2, size + 2), np.uint8)
    lines = np.round((uv_edges + 1.0) * (1 << _SUBPIXEL_BITS)).astype(np.int32)
    cv2.polylines(canvas, list(lines), False, 255, 1, cv2.LINE_8, _SUBPIXEL_BITS)
    flood = canvas.copy()
    cv2.floodFill(flood, np.zeros((size + 4, size + 4), np.uint8), (0, 0), 128)
    return (flood != 128)[1:-1, 1:-1]


def _run_lengths(mask, start_uv, step_uv, inside, max_steps):
    """(P,) steps from each start along its step until the mask stops being ``inside``."""
    size = mask.shape[0]
    steps = np.arange(1, max_steps + 1)
    uv = start_uv[:, None, :] + steps[None, :, None] * step_uv[:, None, :]
    cols = np.clip(np.round(uv[..., 0]).astype(int), 0, size - 1)
    rows = np.clip(np.round(uv[..., 1]).astype(int), 0, size - 1)
    outside_image = np.any((uv < 0) | (uv > size - 1), axis=2)
    changed = (mask[rows, cols] != inside) | outside_image
    return np.where(changed.any(axis=1), changed.argmax(axis=1) + 1, max_steps)


def _view_contour(table, rotation, focal, size, count):
    """Contour points (P, 3), outward normals (P, 3), run lengths (P,), (P,) in metres."""
    translation = np.array([0.0, 0.0, TEMPLATE_DISTANCE_M])
    camera_position = -rotation.T @ translation
    edges = table.contour_edges(camera_position)
    points_cam = table.vertices @ rotation.T + translation
    uv = focal * points_cam[:, :2] / points_cam[:, 2:] + size / 2.0
    mask = _silhouette(uv[edges], size)
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL,
                                   cv2.CHAIN_APPROX_NONE)
    if not contours:
        raise InputError('the mesh has no silhouette from one of the template views')
    contour = np.concatenate([c[:, 0, :] for c in contours]).astype(float)
    pick = np.linspace(0, len(contour), count, endpoint=False).astype(int)
    ahead = contour[(pick + _TANGENT_STEP) % len(contour)]
    behind = contour[(pick - _TANGENT_STEP) % len(contour)]
    tangent = ahead - behind
    normal_uv = np.stack([tangent[:, 1], -tangent[:, 0]], axis=1)
    normal_uv /= np.maximum(np.linalg.norm(normal_uv, axis=1, keepdims=True), 1e-9)
    centre_uv = contour[pick]
    probe = np.round(centre_uv + 2.0 * normal_uv).astype(int).clip(0, size - 1)
    flip = mask[probe[:, 1], probe[:, 0]]
    normal_uv[flip] *= -1.0
    # The model point under each contour pixel: the nearest point of a contour-generator
    # edge, moved within its depth plane onto the pixel.
    samples = np.linspace(0.0, 1.0, 5)
    edge_points = (points_cam[edges[:, 0], None, :] * (1 - samples[None, :, None])
                   + points_cam[edges[:, 1], None, :] * samples[None, :, None]).reshape(-1, 3)
    edge_uv = focal * edge_points[:, :2] / edge_points[:, 2:] + size / 2.0
    _, nearest = cKDTree(edge_uv).query(centre_uv)
    depth = edge_points[nearest, 2]
    xy = (centre_uv - size / 2.0) * depth[:, None] / focal
    points = (np.column_stack([xy, depth]) - translation) @ rotation
    normals = np.column_stack([normal_uv, np.zeros(len(normal_uv))]) @ rotation
    max_steps = size
    inward = _run_lengths(mask, centre_uv, -normal_uv, True, max_steps)
    outward = _run_lengths(mask, centre_uv, normal_uv, False, max_steps)
    metres_per_px = depth / focal
    return points, normals, inward * metres_per_px, outward * metres_per_px


def build_viewpoint_model(vertices: npt.ArrayLike, faces: npt.ArrayLike, diameter: float,
                          subdivisions: int = 2, points_per_view: int = 200,
                          progress: Callable[[int, int], None] | None = None
                          ) -> ViewpointModel:
    """
    Compute the sparse viewpoint model of a mesh.

    Args:
        vertices: (V, 3) mesh vertices, metres, model frame (origin near the centre).
        faces: (F, 3) triangle vertex indices.
        diameter: object diameter, metres.
        subdivisions: icosphere level of the view directions (2: 162 views, 3: 642).
        points_per_view: contour points stored per view.
        progress: optional callable(done, total) called after each view.

    """
    if not diameter > 0.0:
        raise InputError(f'object diameter must be > 0, got {diameter}')
    table = _EdgeTable(vertices, faces)
    directions = geodesic_directions(subdivisions)
    focal = TEMPLATE_DIAMETER_PX * TEMPLATE_DISTANCE_M / diameter
    size = int(2 * TEMPLATE_DIAMETER_PX)
    views = []
    for k, direction in enumerate(directions):
        views.append(_view_contour(table, look_at_rotation(direction), focal, size,
                                   points_per_view))
        if progress is not None:
            progress(k + 1, len(directions))
    points, normals, inward, outward = (np.stack(v).astype(np.float32) for v in zip(*views))
    return ViewpointModel(directions, points, normals, inward,
                          np.minimum(outward, np.float32(diameter)), float(diameter))


def mesh_digest(vertices: npt.ArrayLike, faces: npt.ArrayLike, subdivisions: int,
                points_per_view: int) -> str:
    """Cache key of a viewpoint model: the mesh and the build settings."""
    digest = hashlib.sha256()
    for array in (np.ascontiguousarray(vertices, dtype=np.float64),
                  np.ascontiguousarray(faces, dtype=np.int64)):
        digest.update(array.tobytes())
    digest.update(f'{subdivisions},{points_per_view},{TEMPLATE_DIAMETER_PX},'
                  f'{TEMPLATE_DISTANCE_M},{CACHE_FORMAT}'.encode())
    return digest.hexdigest()[:16]
