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
Offline evaluation of the pipeline on BOP frames, with the report's JSON layout.

An instance counts when its visible fraction is at least ``min_visib`` (0.1, as BOP does);
an instance the pipeline misses counts as a failure in every recall. Medians and means of
errors are taken over the instances that were found.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
import math
from typing import Any, TYPE_CHECKING

import numpy as np
import numpy.typing as npt
from tqdm import tqdm

from bbpose_ros.core.eval import metrics
from bbpose_ros.core.eval.tables import format_object_table
from bbpose_ros.core.geometry.boxes import box_iou
from bbpose_ros.core.geometry.projection import projected_box_uv
from bbpose_ros.core.geometry.rotations import euler_error_deg, perturb_pose
from bbpose_ros.core.pipeline.latency import StageTimer, timing_summary
from bbpose_ros.core.pipeline.pose_pipeline import dense_masks, PosePipeline
from bbpose_ros.core.pipeline.poses import Detection, FrameResult, PoseEstimate
from bbpose_ros.core.util.errors import InputError

if TYPE_CHECKING:
    from bbpose_ros.core.data.bop import BopFrame, GroundTruthInstance
    from bbpose_ros.core.data.models import ObjectModel
    from bbpose_ros.core.geometry.camera import CameraIntrinsics

ADD_THRESHOLD = 0.1           # fraction of the diameter
PROJ_THRESHOLD_PX = 5.0
RE_THRESHOLD_DEG = 5.0
TE_THRESHOLD_M = 0.05
CONFIDENCE_THRESHOLDS = tuple(k / 10.0 for k in range(10))
MATCH_IOU = 0.1               # a pose is scored against the instance its box overlaps
DETECTION_IOU = 0.5

POSE_KEYS = ('n', 'detected', 'add_s_recall', 'cm5deg5', 'proj5px', 're_median_deg',
             'te_median_mm', 'euler_mean_deg', 'te5cm_uncut')


@dataclass(frozen=True)
class InstanceScore:
    """
    Errors of one counted ground-truth instance (NaN where missed), and how visible it is.

    ``confidence`` is the pose's (``PoseEstimate.confidence``: the refinement score when
    refined, else the detection score), NaN where missed; ``source`` where the pose came
    from (``PoseEstimate.source``), None where missed; ``key`` names the instance
    ('<scene_id>/<image_id>/<index in the frame's ground truth>', ``instance_key``), so two
    runs over the same frames pair instance by instance (``paired``).
    """

    object_name: str
    detected: bool
    box_inside_image: bool
    add_error: float
    add_threshold: float
    re_deg: float
    te_m: float
    proj_px: float
    euler_deg: float
    visib_fract: float
    confidence: float
    source: str | None = None
    key: str = ''

    def record(self) -> dict[str, Any]:
        """Return the instance as a JSON-ready dict: errors in mm and degrees, passes."""
        add_ok, cm_deg = (bool(x[0]) for x in _passes([self]))
        return {'key': self.key, 'object': self.object_name, 'visib_fract': self.visib_fract,
                'found': self.detected, 'source': self.source,
                'confidence': _finite_or_none(self.confidence),
                'add_mm': _finite_or_none(self.add_error * 1000.0),
                'add_threshold_mm': self.add_threshold * 1000.0,
                're_deg': _finite_or_none(self.re_deg),
                'te_mm': _finite_or_none(self.te_m * 1000.0),
                'proj_px': _finite_or_none(self.proj_px),
                'add_s': add_ok, 'cm5deg5': cm_deg,
                'proj5px': bool(self.proj_px < PROJ_THRESHOLD_PX)}


def instance_key(frame: BopFrame, index: int) -> str:
    """Name instance ``index`` of a frame's ground truth: '<scene_id>/<image_id>/<index>'."""
    return f'{frame.scene_id}/{frame.image_id}/{index}'


def _finite_or_none(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


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


def score_instance(model: ObjectModel, instance: GroundTruthInstance, pose: PoseEstimate | None,
                   camera: CameraIntrinsics) -> InstanceScore:
    """Score one ground-truth instance against a PoseEstimate (or None: missed)."""
    inside = bool(instance.box_uv[0] >= -0.5 and instance.box_uv[1] >= -0.5
                  and instance.box_uv[2] <= camera.width - 0.5
                  and instance.box_uv[3] <= camera.height - 0.5)
    threshold = ADD_THRESHOLD * model.diameter
    if pose is None:
        nan = float('nan')
        return InstanceScore(model.name, False, inside, nan, threshold, nan, nan, nan, nan,
                             instance.visib_fract, nan)
    args = (pose.rotation, pose.translation, instance.rotation, instance.translation)
    distance = metrics.adi if model.is_symmetric else metrics.add
    re_deg, te_m = metrics.cm_deg_errors(*args, model.symmetry_transforms)
    return InstanceScore(
        model.name, True, inside, distance(*args, model.eval_points), threshold, re_deg, te_m,
        metrics.proj(*args, camera.k, model.eval_points),
        float(euler_error_deg(pose.rotation, instance.rotation)[0]), instance.visib_fract,
        float(pose.confidence), pose.source)


def summarize(scores: Sequence[InstanceScore]) -> dict[str, float]:
    """Per-object figures (POSE_KEYS) from a list of InstanceScore of one object."""
    def errors(name):
        return _values(scores, name)

    found = errors('re_deg')[~np.isnan(errors('re_deg'))]
    te_found = errors('te_m')[~np.isnan(errors('te_m'))]
    inside = np.array([s.box_inside_image for s in scores], dtype=bool)
    add_ok, cm_deg = _passes(scores)
    return {
        'n': len(scores),
        'detected': int(sum(s.detected for s in scores)),
        'add_s_recall': float(add_ok.mean()) if scores else math.nan,
        'cm5deg5': float(cm_deg.mean()) if scores else math.nan,
        'proj5px': metrics.recall(errors('proj_px'), PROJ_THRESHOLD_PX),
        're_median_deg': float(np.median(found)) if found.size else math.nan,
        'te_median_mm': float(np.median(te_found) * 1e3) if te_found.size else math.nan,
        'euler_mean_deg': float(np.nanmean(errors('euler_deg'))) if found.size else math.nan,
        'te5cm_uncut': metrics.recall(errors('te_m')[inside], TE_THRESHOLD_M),
    }


def confidence_sweep(scores: Mapping[str, Sequence[InstanceScore]],
                     thresholds: Sequence[float] = CONFIDENCE_THRESHOLDS
                     ) -> list[dict[str, float]]:
    """
    Tell what a minimum confidence (the node's ``refine_min_score``) keeps, all objects pooled.

    Returns:
        Per threshold, {'min_confidence', 'kept': share of the found poses scoring at least
        it, 'add_s_precision' and 'cm5deg5_precision': shares of those kept that pass
        ADD(-S) and 5 cm / 5 deg (NaN when none is kept)}.

    """
    found = [s for group in scores.values() for s in group if s.detected]
    confidence = np.array([s.confidence for s in found], dtype=float)
    add_ok, cm_deg_ok = _passes(found)
    sweep = []
    for threshold in thresholds:
        kept = confidence >= threshold
        sweep.append({
            'min_confidence': float(threshold),
            'kept': float(kept.mean()) if found else math.nan,
            'add_s_precision': float(add_ok[kept].mean()) if kept.any() else math.nan,
            'cm5deg5_precision': float(cm_deg_ok[kept].mean()) if kept.any() else math.nan,
        })
    return sweep


def _passes(scores):
    """(N,) bool each: ADD(-S) passed, 5 cm / 5 deg passed (a missed instance fails both)."""
    with np.errstate(invalid='ignore'):
        return (_values(scores, 'add_error') < _values(scores, 'add_threshold'),
                (_values(scores, 're_deg') < RE_THRESHOLD_DEG)
                & (_values(scores, 'te_m') < TE_THRESHOLD_M))


def _values(scores, name):
    """(N,) float array of one InstanceScore field (NaN where the instance was missed)."""
    return np.array([getattr(s, name) for s in scores], dtype=float)


def mean_over_objects(per_object: Mapping[str, Mapping[str, Any]],
                      keys: Iterable[str]) -> dict[str, float]:
    """Average each key over the objects that have a finite value for it."""
    mean = {}
    for key in keys:
        values = [v[key] for v in per_object.values() if _finite(v.get(key))]
        mean[key] = float(np.mean(values)) if values else math.nan
    return mean


def ground_truth_detections(instances: Iterable[GroundTruthInstance]) -> list[Detection]:
    """Make detections with score 1 from ground-truth instances (the ``--boxes gt`` oracle)."""
    return [Detection(i.object_name, 1.0, i.box_uv) for i in instances]


def evaluate(frames: Sequence[BopFrame], pipeline: PosePipeline, boxes: str = 'gt',
             rotation: str = 'gt', min_visib: float = 0.1,
             progress: bool = True) -> dict[str, Any]:
    """Run the pipeline over BOP frames and score it (``score_frames``, ``make_report``)."""
    scores, timings = score_frames(frames, pipeline, boxes, rotation, min_visib, progress)
    return make_report(scores, timings, len(frames))


def make_report(scores: Mapping[str, Sequence[InstanceScore]],
                timings: Iterable[Mapping[str, float]], frame_count: int) -> dict[str, Any]:
    """
    Make the report dict of ``score_frames``' results.

    Returns:
        {'objects': {name: POSE_KEYS}, 'mean': {...}, 'confidence': ``confidence_sweep``,
        'sources': ``source_summary``, 'timing_ms': {...}, 'frames': count}.

    """
    return dict(summarize_objects(scores), confidence=confidence_sweep(scores),
                sources=source_summary(scores), timing_ms=timing_summary(timings),
                frames=frame_count)


def source_summary(scores: Mapping[str, Sequence[InstanceScore]]) -> dict[str, Any]:
    """
    Where the poses that found an instance came from, pooled over the objects.

    Returns:
        {source: {'n': instances found from it, 'add_s_recall', 'cm5deg5': their share
        right}} (``PoseEstimate.source``), most frequent first.

    """
    pooled = [s for object_scores in scores.values() for s in object_scores if s.detected]
    summary = {}
    for source, _ in Counter(s.source for s in pooled).most_common():
        chosen = [s for s in pooled if s.source == source]
        add_ok, cm_deg = _passes(chosen)
        summary[source] = {'n': len(chosen), 'add_s_recall': float(np.mean(add_ok)),
                           'cm5deg5': float(np.mean(cm_deg))}
    return summary


def score_frames(frames: Sequence[BopFrame], pipeline: PosePipeline, boxes: str = 'gt',
                 rotation: str = 'gt', min_visib: float = 0.1, progress: bool = True,
                 perturb: tuple[float, float] | None = None, seed: int = 0,
                 perturb_direction: str = 'random', fuse: str = 'none',
                 camera_poses: Sequence[np.ndarray] | None = None
                 ) -> tuple[dict[str, list[InstanceScore]], list[dict[str, float]]]:
    """
    Run the pipeline over BOP frames and score every counted instance.

    Args:
        frames: BopFrame list.
        pipeline: a PosePipeline whose ``models`` are the objects to evaluate.
        boxes: 'gt' (amodal ground-truth boxes of the counted instances) or 'detector'.
        rotation: 'gt' (ground-truth rotations of the matched instances) or 'estimator'.
        min_visib: instances less visible than this are not counted.
        progress: show a progress bar on stderr.
        perturb: (degrees, metres): instead of the Bounding Box Equation, start each pose
            from its ground truth turned by that angle about a random axis and moved by that
            distance as ``perturb_direction`` says (seeded), then run the pipeline's refiner on it
            (none: the perturbed pose is scored). Needs boxes and rotation 'gt'.
        seed: seed of the perturbations.
        perturb_direction: how the translation is moved, ``rotations.PERTURB_DIRECTIONS``:
            'random' (any direction) or 'ray' (along the viewing ray, as a box of the wrong
            size moves it).
        fuse: 'none' scores each frame's own poses; 'causal' or 'final' the map of its
            scene (``fusion.fused_poses``), built from ``camera_poses``.
        camera_poses: with ``fuse``, each frame's (4, 4) world_from_camera.

    Returns:
        ({name: [InstanceScore]}, [per-frame stage timings in ms]).

    """
    if perturb is not None and (boxes != 'gt' or rotation != 'gt'):
        raise InputError('perturbing the ground truth needs ground-truth boxes and rotations')
    rng = np.random.default_rng(seed)
    results = [_estimate_frame(pipeline, frame, _counted(frame, pipeline.models, min_visib),
                               boxes, rotation, perturb, rng, perturb_direction)
               for frame in tqdm(frames, desc='evaluating', unit='frame', disable=not progress)]
    poses = [result.poses for result in results]
    if fuse != 'none':
        from bbpose_ros.core.eval.fusion import fused_poses
        poses = fused_poses(frames, poses, camera_poses, pipeline.models, pipeline.options,
                            fuse)
    scores = {name: [] for name in pipeline.models}
    for frame, frame_poses in zip(frames, poses):
        indices = _counted(frame, pipeline.models, min_visib)
        counted = [frame.instances[k] for k in indices]
        for k, score in zip(indices, score_frame(pipeline.models, counted, frame_poses,
                                                 frame.camera)):
            scores[score.object_name].append(replace(score, key=instance_key(frame, k)))
    return scores, [result.timings_ms for result in results]


def _counted(frame, models, min_visib):
    """Indices of the frame's ground-truth instances that count (modelled, visible enough)."""
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
        truths = _match_to_truth(detections, frame.instances)
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


def score_frame(models: Mapping[str, ObjectModel], instances: Sequence[GroundTruthInstance],
                poses: Sequence[PoseEstimate], camera: CameraIntrinsics) -> list[InstanceScore]:
    """Score each counted instance of a frame against the pose that localises it (or none)."""
    return [score_instance(models[instance.object_name], instance, pose, camera)
            for instance, pose in zip(instances,
                                      _poses_for_instances(models, poses, instances, camera))]


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


def summarize_objects(scores: Mapping[str, Sequence[InstanceScore]]) -> dict[str, Any]:
    """Make the report's {'objects': {name: POSE_KEYS}, 'mean'} from {name: [InstanceScore]}."""
    per_object = {name: summarize(s) for name, s in scores.items()}
    return {'objects': per_object, 'mean': mean_over_objects(per_object, POSE_KEYS)}


def _match_to_truth(detections, instances):
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


def _poses_for_instances(models, poses, instances, camera):
    """
    For each counted instance, the pose that localises it (or None).

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
    for pose, truth in zip(poses, _match_to_truth(boxed_poses, boxed_truths)):
        if truth is not None:
            by_truth[id(truth)] = pose
    return [by_truth.get(id(t)) for t in boxed_truths]


def _finite(value):
    return isinstance(value, (int, float)) and math.isfinite(value)


TABLE_COLUMNS = (('n', 'n', '{:d}'), ('detected', 'found', '{:d}'),
                 ('add_s_recall', 'ADD(-S)', '{:.3f}'), ('cm5deg5', '5cm5deg', '{:.3f}'),
                 ('proj5px', 'proj5px', '{:.3f}'), ('re_median_deg', 're_med_deg', '{:.2f}'),
                 ('te_median_mm', 'te_med_mm', '{:.1f}'),
                 ('euler_mean_deg', 'euler_deg', '{:.2f}'))


def format_report(report: Mapping[str, Any]) -> str:
    """Format the per-object table of a report, with the mean row and stage timings."""
    lines = [format_object_table(report['objects'], report['mean'], TABLE_COLUMNS, 11)]
    timing = ', '.join(f'{stage} {t["median"]:.2f} ms (p95 {t["p95"]:.2f})'
                       for stage, t in report.get('timing_ms', {}).items())
    if timing:
        lines.append(f'timing per frame: {timing}')
    if report.get('sources'):
        lines.append('poses found from: ' + '; '.join(
            f'{source} {row["n"]} (ADD(-S) {row["add_s_recall"]:.3f}, 5cm5deg '
            f'{row["cm5deg5"]:.3f})' for source, row in report['sources'].items()))
    if report.get('confidence'):
        lines.append('minimum confidence: share of found poses kept, and of those kept the '
                     'share passing ADD(-S) / 5cm5deg')
        lines += [f'  >= {row["min_confidence"]:.1f}: kept {row["kept"]:.2f}, ADD(-S) '
                  f'{row["add_s_precision"]:.3f}, 5cm5deg {row["cm5deg5_precision"]:.3f}'
                  for row in report['confidence']]
    return '\n'.join(lines)
