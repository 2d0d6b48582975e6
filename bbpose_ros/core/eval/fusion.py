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
Scoring the map: each frame's poses replaced by the scene's map, seen from that frame.

``bbpose eval --fuse``: the frames of one BOP scene are one static scene (a map is started
afresh for each), in image id order, each with its camera pose. ``causal`` gives each frame
the map built from the frames up to it (what a robot has when the image arrives);
``final`` gives every frame the map after the whole scene (what it has after looking).
Only images, camera poses and the pipeline's poses feed the map, never the ground truth.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from itertools import groupby
from typing import TYPE_CHECKING

import numpy as np

from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.pipeline.poses import PoseEstimate
from bbpose_ros.core.scene.object_map import ObjectMap
from bbpose_ros.core.util.errors import InputError

if TYPE_CHECKING:
    from bbpose_ros.core.data.bop import BopFrame
    from bbpose_ros.core.data.models import ObjectModel

FUSE_MODES = ('none', 'causal', 'final')
# The stamp a frame is given in the map: its image id at a 30 Hz camera's period.
FRAME_PERIOD_NS = 33_333_333


def frame_camera_poses(frames: Sequence[BopFrame], noise: tuple[float, float] | None = None,
                       seed: int = 0) -> list[np.ndarray]:
    """
    (4, 4) world_from_camera of each frame, with ``noise`` (mm, deg) added if given.

    Raises InputError naming the first frame whose scene_camera.json has no camera pose.
    """
    from bbpose_ros.core.eval.static_stretches import noisy_pose
    rng = np.random.default_rng(seed)
    poses = []
    for frame in frames:
        if frame.world_from_camera is None:
            raise InputError(
                f'scene {frame.scene_id} image {frame.image_id} has no camera pose '
                '(cam_R_w2c / cam_t_w2c in its scene_camera.json); bbpose static-scenes '
                'writes a labelled split as static scenes with camera poses')
        pose = frame.world_from_camera
        poses.append(pose if noise is None else noisy_pose(pose, *noise, rng))
    return poses


def fused_poses(frames: Sequence[BopFrame], poses: Sequence[Sequence[PoseEstimate]],
                camera_poses: Sequence[np.ndarray], models: Mapping[str, ObjectModel],
                options: PipelineOptions, mode: str) -> list[list[PoseEstimate]]:
    """
    Each frame's poses as the map gives them (module docstring), frames in scene order.

    ``poses``: the pipeline's poses of each frame (camera frame); ``camera_poses``: each
    frame's (4, 4) world_from_camera.
    """
    if mode not in FUSE_MODES[1:]:
        raise InputError(f'fuse: {mode!r} is not one of {", ".join(FUSE_MODES[1:])}')
    fused = []
    order = range(len(frames))
    for _, scene in groupby(order, key=lambda k: frames[k].scene_id):
        scene = list(scene)
        scene_map = ObjectMap(models, options)
        views = {}
        for k in scene:
            views[k] = scene_map.add_view(frames[k].image_id * FRAME_PERIOD_NS, camera_poses[k],
                                          frames[k].camera, poses[k])
            if mode == 'causal':
                fused.append(scene_map.poses_in_view(camera_poses[k], frames[k].camera,
                                                     poses[k], views[k]))
        if mode == 'final':
            fused.extend(scene_map.poses_in_view(camera_poses[k], frames[k].camera, poses[k],
                                                 views[k]) for k in scene)
    return fused
