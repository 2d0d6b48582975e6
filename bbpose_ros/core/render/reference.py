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
A small numpy z-buffer rasteriser: the test oracle of ``MeshRenderer``.

Slow and simple on purpose. A pixel belongs to a triangle when its centre (OpenCV
convention: pixel (col, row) is centred at (u, v) = (col, row)) lies inside or on the edge of
the projected triangle; depth is interpolated perspective-correctly (1/z linear in the image).
"""

import numpy as np
import numpy.typing as npt

from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.projection import transform_points
from bbpose_ros.core.util.errors import InputError

# Candidate pixels evaluated per chunk (bounds memory for large triangles).
_CHUNK_PIXELS = 1 << 21


def render_depth(camera: CameraIntrinsics, vertices: npt.ArrayLike, faces: npt.ArrayLike,
                 rotation: npt.ArrayLike, translation: npt.ArrayLike) -> np.ndarray:
    """
    Depth image (H, W) float64 of a mesh at a pose: z in metres, inf where uncovered.

    ``vertices`` (V, 3) model points in metres, ``faces`` (F, 3) indices, ``rotation``
    (3, 3) model to camera, ``translation`` (3,) metres. The whole mesh must be in front of
    the camera (z > 0), else InputError.
    """
    points = transform_points(vertices, rotation, translation)
    if np.any(points[:, 2] <= 0.0):
        raise InputError('the reference rasteriser needs the whole mesh in front of the camera')
    uv = camera.project(points)
    tri_uv = uv[np.asarray(faces)]
    inv_z = 1.0 / points[np.asarray(faces), 2]
    area = _edge(tri_uv[:, 0], tri_uv[:, 1], tri_uv[:, 2])
    col0 = np.maximum(np.ceil(tri_uv[..., 0].min(axis=1)), 0).astype(int)
    row0 = np.maximum(np.ceil(tri_uv[..., 1].min(axis=1)), 0).astype(int)
    col1 = np.minimum(np.floor(tri_uv[..., 0].max(axis=1)), camera.width - 1).astype(int)
    row1 = np.minimum(np.floor(tri_uv[..., 1].max(axis=1)), camera.height - 1).astype(int)
    keep = (col0 <= col1) & (row0 <= row1) & (np.abs(area) > 1e-12)
    depth = np.full(camera.height * camera.width, np.inf)
    span = np.maximum(col1 - col0, row1 - row0) + 1
    # Triangles grouped by the power-of-two size of their pixel box: one grid per group.
    size_class = np.ceil(np.log2(np.maximum(span, 1))).astype(int)
    for size in np.unique(size_class[keep]):
        side = 1 << size
        chosen = np.flatnonzero(keep & (size_class == size))
        step = max(1, _CHUNK_PIXELS // (side * side))
        for start in range(0, len(chosen), step):
            _fill(depth, camera.width, chosen[start:start + step], side, tri_uv, inv_z, area,
                  col0, row0, col1, row1)
    return depth.reshape(camera.height, camera.width)


def render_silhouette(camera: CameraIntrinsics, vertices: npt.ArrayLike, faces: npt.ArrayLike,
                      rotation: npt.ArrayLike, translation: npt.ArrayLike) -> np.ndarray:
    """Silhouette (H, W) bool of a mesh at a pose (arguments as in ``render_depth``)."""
    return np.isfinite(render_depth(camera, vertices, faces, rotation, translation))


def _edge(a, b, p):
    """Twice the signed area of triangles (a, b, p); arrays (..., 2)."""
    return (b[..., 0] - a[..., 0]) * (p[..., 1] - a[..., 1]) - \
        (b[..., 1] - a[..., 1]) * (p[..., 0] - a[..., 0])


def _fill(depth, width, tris, side, tri_uv, inv_z, area, col0, row0, col1, row1):
    """Z-buffer the triangles ``tris`` over side x side pixel grids from their box corner."""
    offsets = np.arange(side)
    cols = col0[tris, None, None] + offsets[None, None, :]
    rows = row0[tris, None, None] + offsets[None, :, None]
    pixel = np.stack(np.broadcast_arrays(cols, rows), axis=-1).astype(float)
    a, b, c = (tri_uv[tris, k, None, None, :] for k in range(3))
    sign = np.sign(area[tris])[:, None, None]
    w0 = _edge(b, c, pixel) * sign
    w1 = _edge(c, a, pixel) * sign
    w2 = _edge(a, b, pixel) * sign
    inside = (w0 >= 0) & (w1 >= 0) & (w2 >= 0) & (cols <= col1[tris, None, None]) & \
        (rows <= row1[tris, None, None])
    total = np.abs(area[tris])[:, None, None]
    inv = (w0 * inv_z[tris, 0, None, None] + w1 * inv_z[tris, 1, None, None] +
           w2 * inv_z[tris, 2, None, None]) / total
    t, r, q = np.nonzero(inside)
    np.minimum.at(depth, rows[t, r, 0] * width + cols[t, 0, q], 1.0 / inv[t, r, q])
