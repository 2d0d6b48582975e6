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
The teacher's poses through the map of each static scene: labels with the views' depth.

Where the recording carries the camera's pose (BOP's ``cam_R_w2c`` / ``cam_t_w2c``, a bag's
/tf), the teacher's poses of one static scene are fused into its map
(``core.scene.object_map.ObjectMap``, after the whole scene) and each frame's poses are
replaced by the map's, seen from that frame: a single view's depth, which the students
would otherwise learn the bias of, becomes the one the views agree on. A teacher pose the
map has no object for, or a frame without a camera pose, keeps the teacher's own. The
detection, its score and the confidence stay the teacher's (the gates judge them); the
amodal box is the mesh's at the map's pose.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from itertools import groupby

from bbpose_ros.core.adaptation.frames import RecordedFrame
from bbpose_ros.core.adaptation.teacher import TeacherPose
from bbpose_ros.core.data.models import ObjectModel
from bbpose_ros.core.geometry.projection import projected_box_uv
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.pipeline.poses import Detection, PoseEstimate
from bbpose_ros.core.scene.object_map import FRAME_PERIOD_NS, ObjectMap
from bbpose_ros.core.util.errors import InputError


def mapped_teacher_poses(frames: Sequence[RecordedFrame],
                         poses: Mapping[str, Sequence[TeacherPose]],
                         models: Mapping[str, ObjectModel],
                         options: PipelineOptions) -> tuple[dict[str, list[TeacherPose]], int]:
    """
    Each frame's teacher poses with the map's where it has them (module docstring).

    ``poses``: {frame key: [TeacherPose]}; ``options``: the ``map_*`` settings. Returns
    ({frame key: [TeacherPose]}, how many poses the map moved).
    """
    mapped = {key: list(found) for key, found in poses.items()}
    moved = 0
    placed = [(k, f) for k, f in enumerate(frames) if f.world_from_camera is not None]
    for _, scene in groupby(placed, key=lambda item: item[1].scene):
        scene = list(scene)
        scene_map = ObjectMap(models, options)
        views = {f.key: scene_map.add_view(k * FRAME_PERIOD_NS, f.world_from_camera, f.camera,
                                           [_estimate(p) for p in poses[f.key]])
                 for k, f in scene}
        for _, frame in scene:
            own = [_estimate(p) for p in poses[frame.key]]
            in_view = {p.object_name: p for p in scene_map.poses_in_view(
                frame.world_from_camera, frame.camera, own, views[frame.key])}
            for index, pose in enumerate(mapped[frame.key]):
                better = in_view.get(pose.object_name)
                if better is None:
                    continue
                try:
                    box = projected_box_uv(frame.camera, models[pose.object_name].hull_points,
                                           better.rotation, better.translation)
                except InputError:          # part of the mesh behind the camera: keep it
                    continue
                mapped[frame.key][index] = replace(pose, rotation=better.rotation,
                                                   translation=better.translation, box_uv=box)
                moved += 1
    return mapped, moved


def _estimate(pose: TeacherPose) -> PoseEstimate:
    """Return the teacher's pose as the map takes it (its detection, its confidence)."""
    return PoseEstimate(Detection(pose.object_name, pose.detection_score,
                                  pose.detection_box_uv), pose.rotation, pose.translation,
                        pose.confidence)
