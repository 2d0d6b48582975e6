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
Points at a pose and their projection.

The helpers that the metrics, the renderers, the ground truth and the evaluation share.

Poses are model-to-camera: x_cam = R x_model + t, metres. Pixel coordinates follow
``CameraIntrinsics``: the centre of pixel (col, row) is at (u, v) = (col, row), so pixel
(col, row) spans [col - 0.5, col + 0.5] x [row - 0.5, row + 0.5]. Boxes are
[u_min, v_min, u_max, v_max] in these coordinates.
"""

import numpy as np
import numpy.typing as npt

from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.util.errors import InputError


def transform_points(points: npt.ArrayLike, rotation: npt.ArrayLike,
                     translation: npt.ArrayLike) -> np.ndarray:
    """Map (N, 3) model points to the camera frame: x_cam = R x + t (metres)."""
    return np.asarray(points, dtype=float) @ np.asarray(rotation, dtype=float).T \
        + np.asarray(translation, dtype=float).reshape(1, 3)


def project_with_k(points_cam: npt.ArrayLike, k: npt.ArrayLike) -> np.ndarray:
    """Project (N, 3) camera-frame points with a 3x3 camera matrix K: (N, 2) pixels."""
    uvw = np.asarray(points_cam, dtype=float) @ np.asarray(k, dtype=float).T
    return uvw[:, :2] / uvw[:, 2:3]


def projected_box_uv(camera: CameraIntrinsics, points: npt.ArrayLike, rotation: npt.ArrayLike,
                     translation: npt.ArrayLike) -> np.ndarray:
    """
    Compute the amodal box (4,) [u_min, v_min, u_max, v_max] of (N, 3) points at a pose.

    The extremes of the projected points, continuous pixels, possibly outside the image.
    Pass a mesh's convex-hull vertices for speed: the extremes always lie among them. Points
    at or behind the camera (z <= 0) have no projection and are an InputError.
    """
    points_cam = transform_points(points, rotation, translation)
    if np.any(points_cam[:, 2] <= 0.0):
        raise InputError('cannot project a box: part of the object is behind the camera')
    uv = camera.project(points_cam)
    return np.concatenate([uv.min(axis=0), uv.max(axis=0)])
