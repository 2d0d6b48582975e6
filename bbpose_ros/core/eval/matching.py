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
Matching poses and detections to ground-truth instances, through their boxes.

A detection is matched by its box (``match_by_score``, greedy, highest score first); a pose
by the model's box projected at it (``poses_for_instances``), so scoring needs nothing but
poses: the offline pipeline and the ROS node (which publishes poses only) are matched alike.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from bbpose_ros.core.geometry.boxes import box_iou
from bbpose_ros.core.geometry.projection import projected_box_uv
from bbpose_ros.core.pipeline.poses import Detection, PoseEstimate
from bbpose_ros.core.util.errors import InputError

if TYPE_CHECKING:
    from bbpose_ros.core.data.bop import GroundTruthInstance
    from bbpose_ros.core.data.models import ObjectModel
    from bbpose_ros.core.geometry.camera import CameraIntrinsics

MATCH_IOU = 0.1               # a pose is scored against the instance its box overlaps
DETECTION_IOU = 0.5


def match_by_score(boxes_det: npt.ArrayLike, scores: npt.ArrayLike, boxes_gt: npt.ArrayLike,
                   min_iou: float) -> np.ndarray:
    """
    Greedy matching, highest score first, each detection to the free ground truth of most IoU.

    Returns an (N_det,) array of ground-truth indices, -1 where a detection found none with
    IoU >= ``min_iou``.
    """
    matches = np.full(len(boxes_det), -1)
    if len(boxes_det) == 0 or len(boxes_gt) == 0:
        return matches
    iou = box_iou(boxes_det, boxes_gt)
    free = np.ones(len(boxes_gt), dtype=bool)
    for det in np.argsort(-np.asarray(scores), kind='stable'):
        candidates = np.where(free, iou[det], -1.0)
        best = int(np.argmax(candidates))
        if candidates[best] >= min_iou:
            matches[det] = best
            free[best] = False
    return matches


def pose_box(model: ObjectModel, camera: CameraIntrinsics, rotation: npt.ArrayLike,
             translation: npt.ArrayLike) -> np.ndarray:
    """
    Return the box (4,) of the model projected at a pose (``projected_box_uv``).

    A pose with part of the model behind the camera has no box: all NaN, which overlaps
    nothing, so it matches no instance.
    """
    try:
        return projected_box_uv(camera, model.hull_points, rotation, translation)
    except InputError:
        return np.full(4, np.nan)


def match_to_truth(detections: Sequence[Detection],
                   instances: Sequence[GroundTruthInstance]
                   ) -> list[GroundTruthInstance | None]:
    """Find the ground-truth instance each detection localises (or None), per object."""
    truths = [None] * len(detections)
    for name in {d.object_name for d in detections}:
        det_idx = [k for k, d in enumerate(detections) if d.object_name == name]
        gts = [i for i in instances if i.object_name == name]
        matches = match_by_score([detections[k].box_uv for k in det_idx],
                                 [detections[k].score for k in det_idx],
                                 [g.box_uv for g in gts], MATCH_IOU)
        for k, m in zip(det_idx, matches):
            truths[k] = gts[m] if m >= 0 else None
    return truths


def poses_for_instances(models: Mapping[str, ObjectModel],
                        poses: Sequence[PoseEstimate],
                        instances: Sequence[GroundTruthInstance],
                        camera: CameraIntrinsics) -> list[PoseEstimate | None]:
    """
    Return, for each counted instance, the pose that localises it (or None).

    Poses and instances are matched through the model's box projected at each pose, so
    scoring needs nothing but poses: the offline pipeline and the ROS node (which publishes
    poses only) are matched alike.
    """
    def box_of(name, rotation, translation):
        return pose_box(models[name], camera, rotation, translation)

    boxed_poses = [Detection(p.object_name, p.detection.score,
                             box_of(p.object_name, p.rotation, p.translation)) for p in poses]
    boxed_truths = [replace(i, box_uv=box_of(i.object_name, i.rotation, i.translation))
                    for i in instances]
    by_truth = {}
    for pose, truth in zip(poses, match_to_truth(boxed_poses, boxed_truths)):
        if truth is not None:
            by_truth[id(truth)] = pose
    return [by_truth.get(id(t)) for t in boxed_truths]
