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
Random object poses for synthetic scenes.

A pose is built in two steps: an allocentric rotation (how the object looks when centred on
the optical axis: viewpoint elevation, azimuth and in-plane angle) and a translation along
the camera ray through a chosen pixel; ``allocentric_to_egocentric`` then gives the rotation
in the camera frame. Rotations map model to camera coordinates; translations are metres.
"""

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.rotations import allocentric_to_egocentric


def viewpoint_rotation(azimuth: float, elevation: float, inplane: float) -> np.ndarray:
    """
    (3, 3) allocentric rotation of a camera looking at the model origin.

    The camera sits in the model frame at direction (cos(el) cos(az), cos(el) sin(az),
    sin(el)) and is then rolled by ``inplane`` about its optical axis; angles in radians.
    """
    position = np.array([np.cos(elevation) * np.cos(azimuth),
                         np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])
    cos, sin = np.cos(inplane), np.sin(inplane)
    roll = np.array([[cos, -sin, 0.0], [sin, cos, 0.0], [0.0, 0.0, 1.0]])
    return roll @ _look_at(-position[None])[0]


def viewpoint_angles(rotations_allo: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Inverse of ``viewpoint_rotation``: (azimuth, elevation, inplane), each (N,), radians.

    ``rotations_allo`` (N, 3, 3) allocentric rotations; looking straight down or up, the
    azimuth is 0 and all of the turn about the optical axis is ``inplane``.
    """
    rotations = np.asarray(rotations_allo, dtype=float)
    position = -rotations[:, 2]
    elevation = np.arcsin(np.clip(position[:, 2], -1.0, 1.0))
    vertical = np.hypot(position[:, 0], position[:, 1]) < 1e-6
    azimuth = np.where(vertical, 0.0, np.arctan2(position[:, 1], position[:, 0]))
    look_at = _look_at(rotations[:, 2])
    # Row 0 of roll @ look_at is cos(inplane) x - sin(inplane) y of the look-at rows.
    inplane = np.arctan2(-np.einsum('ij,ij->i', rotations[:, 0], look_at[:, 1]),
                         np.einsum('ij,ij->i', rotations[:, 0], look_at[:, 0]))
    return azimuth, elevation, inplane


def _look_at(z_axes):
    """
    (N, 3, 3) camera axes as rows, in the model frame, for viewing directions (N, 3).

    No roll: the camera x axis is horizontal (z x model z), so the model's z axis points up
    in the image; looking straight down or up, x is the model's x axis.
    """
    x_axes = np.cross(z_axes, [0.0, 0.0, 1.0])
    norm = np.linalg.norm(x_axes, axis=1, keepdims=True)
    x_axes = np.where(norm < 1e-6, [1.0, 0.0, 0.0], x_axes / np.maximum(norm, 1e-12))
    return np.stack([x_axes, np.cross(z_axes, x_axes), z_axes], axis=1)


def random_allocentric_rotation(rng: np.random.Generator, elevation_range_deg: Sequence[float],
                                inplane_range_deg: Sequence[float] = (0.0, 360.0)
                                ) -> np.ndarray:
    """
    (3, 3) rotation from a random viewpoint.

    The viewpoint is uniform on the sphere band of the elevation range, at any azimuth, and
    the in-plane rotation uniform in ``inplane_range_deg``.
    """
    low, high = np.sin(np.radians(elevation_range_deg))
    elevation = np.arcsin(rng.uniform(low, high))
    return viewpoint_rotation(rng.uniform(0.0, 2.0 * np.pi), elevation,
                              rng.uniform(*np.radians(inplane_range_deg)))


def pose_at_pixel(camera: CameraIntrinsics, uv: npt.ArrayLike, distance: float,
                  rotation_allo: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """
    Return the egocentric pose (R (3, 3), t (3,)) of an object seen through a pixel.

    The model origin lies at ``distance`` metres on the ray through pixel ``uv`` (continuous
    (u, v)); ``rotation_allo`` is how the object looks in a crop centred on it.
    """
    ray = np.append(camera.normalized(np.asarray(uv, dtype=float)), 1.0)
    ray /= np.linalg.norm(ray)
    rotation = allocentric_to_egocentric(rotation_allo, ray[None])[0]
    return rotation, distance * ray


def random_pixel(rng: np.random.Generator, camera: CameraIntrinsics,
                 margin: float) -> np.ndarray:
    """(2,) pixel uniform over the image grown by ``margin`` x its size on every side."""
    return np.array([rng.uniform(-0.5 - margin * camera.width,
                                 camera.width - 0.5 + margin * camera.width),
                     rng.uniform(-0.5 - margin * camera.height,
                                 camera.height - 0.5 + margin * camera.height)])
