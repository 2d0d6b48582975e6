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
A moving camera over a table-top scene, frame by frame at a camera's rate.

Real video with ground truth does not exist here; a rendered path stands in for a robot's
camera stream: ``TableScenes.sample_with_layout(index, pose)`` renders one scene (its
objects, lights, textures) from each pose of the path, and ``bbpose make-bag --split
train_synth --rate HZ`` makes the frames a bag that ``replay-eval`` plays in real time.

Poses are world-to-camera (4, 4) in the table frame: metres, z up, the table at z = 0.
"""

from __future__ import annotations

import math

import numpy as np

from bbpose_ros.core.synth.stable_poses import yaw_rotation
from bbpose_ros.core.util.errors import InputError


def orbit_path(world_to_camera: np.ndarray, count: int, rate_hz: float, degrees_per_s: float,
               bob_m: float = 0.0, bob_hz: float = 0.5) -> list[np.ndarray]:
    """
    Return ``count`` (4, 4) world-to-camera poses of a camera circling what it looks at.

    Frame i is at time t = i / ``rate_hz`` s: the start pose turned by ``degrees_per_s`` x t
    about the vertical axis through the point where its optical axis meets the table
    (z = 0), so that it keeps looking at that point, then raised by ``bob_m`` x
    sin(2 pi ``bob_hz`` t) metres without turning (a hand's or an arm's up and down).

    Raises:
        InputError: a start that does not look down at the table, a count < 1 or a rate
            <= 0.

    """
    if count < 1 or not rate_hz > 0.0:
        raise InputError(f'a camera path needs count >= 1 and rate > 0, got {count}, '
                         f'{rate_hz}')
    world_to_camera = np.asarray(world_to_camera, dtype=float)
    rotation, translation = world_to_camera[:3, :3], world_to_camera[:3, 3]
    centre = -rotation.T @ translation
    axis = rotation.T @ np.array([0.0, 0.0, 1.0])       # the optical axis, table frame
    if not (axis[2] < 0.0 and centre[2] > 0.0):
        raise InputError('a camera path starts at a camera above the table looking down')
    pivot = centre + axis * (-centre[2] / axis[2])
    poses = []
    for frame in range(count):
        seconds = frame / rate_hz
        turn = yaw_rotation(math.radians(degrees_per_s * seconds))
        lift = np.array([0.0, 0.0, bob_m * math.sin(2.0 * math.pi * bob_hz * seconds)])
        # The camera moves by x -> turn (x - pivot) + pivot + lift in the table frame.
        motion = np.eye(4)
        motion[:3, :3], motion[:3, 3] = turn, pivot - turn @ pivot + lift
        poses.append(world_to_camera @ np.linalg.inv(motion))
    return poses
