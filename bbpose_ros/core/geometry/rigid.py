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
Rigid transforms as (4, 4) homogeneous matrices.

A transform is named for the frames it maps between, target first: ``world_from_camera``
maps a point's camera coordinates to its world coordinates, x_world = R @ x_camera + t.
Translations are in metres.
"""

from typing import Any

import numpy as np
import numpy.typing as npt

from bbpose_ros.core.geometry.rotations import quat_wxyz_to_matrix, xyzw_to_wxyz


def rigid_matrix(rotation: npt.ArrayLike, translation: npt.ArrayLike) -> np.ndarray:
    """Make the (4, 4) transform x -> rotation @ x + translation ((3, 3), (3,) metres)."""
    matrix = np.eye(4)
    matrix[:3, :3] = rotation
    matrix[:3, 3] = translation
    return matrix


def rigid_from_xyzw(translation: npt.ArrayLike, rotation_xyzw: npt.ArrayLike) -> np.ndarray:
    """Make the (4, 4) transform of a translation (3,) and a ROS-order quaternion (x, y, z, w)."""
    return rigid_matrix(quat_wxyz_to_matrix(xyzw_to_wxyz(rotation_xyzw)), translation)


def transform_matrix(transform: Any) -> np.ndarray:
    """(4, 4) parent_from_child of a geometry_msgs/Transform (any object of its fields)."""
    t, q = transform.translation, transform.rotation
    return rigid_from_xyzw([t.x, t.y, t.z], [q.x, q.y, q.z, q.w])


def invert_rigid(transform: npt.ArrayLike) -> np.ndarray:
    """Invert (..., 4, 4) rigid transforms (rotation transposed, translation moved back)."""
    transform = np.asarray(transform, dtype=float)
    rotation_t = np.swapaxes(transform[..., :3, :3], -1, -2)
    inverse = np.zeros_like(transform)
    inverse[..., :3, :3] = rotation_t
    inverse[..., :3, 3] = -np.einsum('...ij,...j->...i', rotation_t, transform[..., :3, 3])
    inverse[..., 3, 3] = 1.0
    return inverse


def is_rigid(transform: npt.ArrayLike, tolerance: float = 1e-6) -> bool:
    """Tell whether a (4, 4) matrix is finite, has a proper rotation and a [0 0 0 1] row."""
    transform = np.asarray(transform, dtype=float)
    if transform.shape != (4, 4) or not np.all(np.isfinite(transform)):
        return False
    rotation = transform[:3, :3]
    return bool(np.allclose(rotation @ rotation.T, np.eye(3), atol=tolerance)
                and abs(np.linalg.det(rotation) - 1.0) < tolerance
                and np.allclose(transform[3], [0.0, 0.0, 0.0, 1.0]))
