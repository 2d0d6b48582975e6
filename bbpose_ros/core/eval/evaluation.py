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
Offline evaluation of the pipeline on BOP frames: run it (or its oracles) and score each frame.

An instance counts when its visible fraction is at least ``min_visib`` (0.1, as BOP does).
The scores and the report's figures are ``instance_scores``'; poses are matched to the
instances by ``matching``.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import replace
from typing import Any, TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from bbpose_ros.core.eval.instance_scores import instance_key, InstanceScore, make_report
from bbpose_ros.core.eval.instance_scores import score_frame
from bbpose_ros.core.eval.matching import match_to_truth
from bbpose_ros.core.geometry.rotations import perturb_pose
from bbpose_ros.core.pipeline.latency import StageTimer
from bbpose_ros.core.pipeline.pose_pipeline import dense_masks, PosePipeline
from bbpose_ros.core.pipeline.poses import Detection, FrameResult, PoseEstimate
from bbpose_ros.core.util.errors import InputError

if TYPE_CHECKING:
    from bbpose_ros.core.data.bop import BopFrame, GroundTruthInstance
    from bbpose_ros.core.data.models import ObjectModel
    from bbpose_ros.core.geometry.camera import CameraIntrinsics


def ground_truth_detections(instances: Iterable[GroundTruthInstance]) -> list[Detection]:
    """Make detections with score 1 from ground-truth instances (the ``--boxes gt`` oracle)."""
    return [Detection(i.object_name, 1.0, i.box_uv) for i in instances]


def evaluate(frames: Sequence[BopFrame], pipeline: PosePipeline, boxes: str = 'gt',
             rotation: str = 'gt', min_visib: float = 0.1,
             progress: bool = True) -> dict[str, Any]:
    """Run the pipeline over BOP frames and score it (``score_frames``, ``make_report``)."""
    scores, timings = score_frames(frames, pipeline, boxes, rotation, min_visib, progress)
    return make_report(scores, timings, len(frames))


def score_frames(frames: Sequence[BopFrame], pipeline: PosePipeline, boxes: str = 'gt',
                 rotation: str = 'gt', min_visib: float = 0.1, progress: bool = True,
                 perturb: tuple[float, float] | None = None, seed: int = 0,
                 perturb_direction: str = 'random'
                 ) -> tuple[dict[str, list[InstanceScore]], list[dict[str, float]]]:
    """
    Run the pipeline over BOP frames and score every counted instance.

    ``estimate_frames`` then ``score_poses``; the arguments are theirs.

    Returns:
        ({name: [InstanceScore]}, [per-frame stage timings in ms]).

    """
    results = estimate_frames(frames, pipeline, boxes, rotation, min_visib, progress,
                              perturb, seed, perturb_direction)
    return (score_poses(frames, [result.poses for result in results], pipeline.models,
                        min_visib), [result.timings_ms for result in results])


def estimate_frames(frames: Sequence[BopFrame], pipeline: PosePipeline, boxes: str = 'gt',
                    rotation: str = 'gt', min_visib: float = 0.1, progress: bool = True,
                    perturb: tuple[float, float] | None = None, seed: int = 0,
                    perturb_direction: str = 'random') -> list[FrameResult]:
    """
    Run the pipeline (or its ground-truth oracles) over BOP frames; a FrameResult each.

    Args:
        frames: BopFrame list.
        pipeline: a PosePipeline whose ``models`` are the objects to evaluate.
        boxes: 'gt' (amodal ground-truth boxes of the counted instances) or 'detector'.
        rotation: 'gt' (ground-truth rotations of the matched instances) or 'estimator'.
        min_visib: instances less visible than this are not counted (nor given as boxes).
        progress: show a progress bar on stderr.
        perturb: (degrees, metres): instead of the Bounding Box Equation, start each pose
            from its ground truth turned by that angle about a random axis and moved by that
            distance as ``perturb_direction`` says (seeded), then run the pipeline's refiner on it
            (none: the perturbed pose is scored). Needs boxes and rotation 'gt'.
        seed: seed of the perturbations.
        perturb_direction: how the translation is moved, ``rotations.PERTURB_DIRECTIONS``:
            'random' (any direction) or 'ray' (along the viewing ray, as a box of the wrong
            size moves it).

    """
    if perturb is not None and (boxes != 'gt' or rotation != 'gt'):
        raise InputError('perturbing the ground truth needs ground-truth boxes and rotations')
    rng = np.random.default_rng(seed)
    return [_estimate_frame(pipeline, frame, _counted(frame, pipeline.models, min_visib),
                            boxes, rotation, perturb, rng, perturb_direction)
            for frame in tqdm(frames, desc='evaluating', unit='frame', disable=not progress)]


def score_poses(frames: Sequence[BopFrame], poses: Sequence[Sequence[PoseEstimate]],
                models: Mapping[str, ObjectModel], min_visib: float = 0.1
                ) -> dict[str, list[InstanceScore]]:
    """Score each frame's poses (camera frame) against its counted instances, by object."""
    scores = {name: [] for name in models}
    for frame, frame_poses in zip(frames, poses):
        indices = _counted(frame, models, min_visib)
        counted = [frame.instances[k] for k in indices]
        for k, score in zip(indices, score_frame(models, counted, frame_poses, frame.camera)):
            scores[score.object_name].append(replace(score, key=instance_key(frame, k)))
    return scores


def _counted(frame, models, min_visib):
    """Return the indices of the frame's ground-truth instances that count (modelled, visible)."""
    return [k for k, i in enumerate(frame.instances)
            if i.object_name in models and i.visib_fract >= min_visib]


def _estimate_frame(pipeline, frame, indices, boxes, rotation, perturb, rng, perturb_direction):
    """Run the pipeline (or its oracles, see score_frames) on one frame: its FrameResult."""
    counted = [frame.instances[k] for k in indices]
    image = frame.load_image()
    detections = ground_truth_detections(counted) if boxes == 'gt' else None
    if rotation == 'gt':
        if detections is None:
            detections = pipeline.detector(image)
        detections = [d for d in detections if d.object_name in pipeline.models]
        truths = match_to_truth(detections, frame.instances)
        keep = [k for k, t in enumerate(truths) if t is not None]
        detections = [detections[k] for k in keep]
        rotations = np.array([truths[k].rotation for k in keep]).reshape(-1, 3, 3)
        if perturb is None:
            result = pipeline.estimate(image, frame.camera, detections, rotations)
        else:
            result = refine_perturbed(pipeline, image, frame.camera, detections,
                                      [truths[k] for k in keep], perturb, rng,
                                      perturb_direction)
    else:
        result = pipeline.estimate(image, frame.camera, detections)
    return result


def refine_perturbed(pipeline: PosePipeline, image_rgb: np.ndarray, camera: CameraIntrinsics,
                     detections: Sequence[Detection], truths: Sequence[GroundTruthInstance],
                     perturb: tuple[float, float], rng: np.random.Generator,
                     direction: str = 'random') -> FrameResult:
    """Refine perturbed ground-truth poses with the pipeline's refiner (see score_frames)."""
    timer = StageTimer()
    poses = [PoseEstimate(d, *perturb_pose(t.rotation, t.translation, perturb[0], perturb[1],
                                           rng, direction), source='given')
             for d, t in zip(detections, truths)]
    if pipeline.refiner is not None and poses:
        masks = choice_masks = None
        if pipeline.correspondences is not None:      # the dense net's masks guide it
            maps = pipeline.correspondences.maps(image_rgb, detections)
            masks, choice_masks = pipeline.masks_of(maps), dense_masks(maps, 'amodal')
        poses = pipeline.refiner(image_rgb, camera, poses, masks, choice_masks)
        timer.lap('refinement')
    return FrameResult(poses, timer.total())
