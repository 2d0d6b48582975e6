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

import numpy as np

from bbpose_ros.core.rotations import allocentric_to_egocentric


def viewpoint_rotation(azimuth, elevation, inplane):
    """
    (3, 3) allocentric rotation of a camera looking at the model origin.

    The camera sits in the model frame at direction (cos(el) cos(az), cos(el) sin(az),
    sin(el)) and is then rolled by ``inplane`` about its optical axis; angles in radians.
    """
    position = np.array([np.cos(elevation) * np.cos(azimuth),
                         np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])
    z_axis = -position
    x_axis = np.cross(z_axis, [0.0, 0.0, 1.0])
    if np.linalg.norm(x_axis) < 1e-6:  # looking straight down or up
        x_axis = np.array([1.0, 0.0, 0.0])
    x_axis /= np.linalg.norm(x_axis)
    look_at = np.stack([x_axis, np.cross(z_axis, x_axis), z_axis])
    cos, sin = np.cos(inplane), np.sin(inplane)
    roll = np.array([[cos, -sin, 0.0], [sin, cos, 0.0], [0.0, 0.0, 1.0]])
    return roll @ look_at


def random_allocentric_rotation(rng, elevation_range_deg):
    """(3, 3) rotation from a viewpoint uniform on the sphere band of the elevation range."""
    low, high = np.sin(np.radians(elevation_range_deg))
    elevation = np.arcsin(rng.uniform(low, high))
    return viewpoint_rotation(rng.uniform(0.0, 2.0 * np.pi), elevation,
                              rng.uniform(0.0, 2.0 * np.pi))


def pose_at_pixel(camera, uv, distance, rotation_allo):
    """
    Return the egocentric pose (R (3, 3), t (3,)) of an object seen through a pixel.

    The model origin lies at ``distance`` metres on the ray through pixel ``uv`` (continuous
    (u, v)); ``rotation_allo`` is how the object looks in a crop centred on it.
    """
    ray = np.append(camera.normalized(np.asarray(uv, dtype=float)), 1.0)
    ray /= np.linalg.norm(ray)
    rotation = allocentric_to_egocentric(rotation_allo, ray[None])[0]
    return rotation, distance * ray


def random_pixel(rng, camera, margin):
    """(2,) pixel uniform over the image grown by ``margin`` x its size on every side."""
    return np.array([rng.uniform(-0.5 - margin * camera.width,
                                 camera.width - 0.5 + margin * camera.width),
                     rng.uniform(-0.5 - margin * camera.height,
                                 camera.height - 0.5 + margin * camera.height)])
