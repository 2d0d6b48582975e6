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
The errors of each ground-truth instance and the report's figures made of them.

An instance the pipeline misses counts as a failure in every recall; medians and means of
errors are taken over the instances that were found.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
import math
from typing import Any, TYPE_CHECKING

import numpy as np

from bbpose_ros.core.eval import metrics
from bbpose_ros.core.eval.matching import poses_for_instances
from bbpose_ros.core.geometry.rotations import euler_error_deg
from bbpose_ros.core.pipeline.latency import timing_summary
from bbpose_ros.core.pipeline.poses import PoseEstimate

if TYPE_CHECKING:
    from bbpose_ros.core.data.bop import BopFrame, GroundTruthInstance
    from bbpose_ros.core.data.models import ObjectModel
    from bbpose_ros.core.geometry.camera import CameraIntrinsics

ADD_THRESHOLD = 0.1           # fraction of the diameter
PROJ_THRESHOLD_PX = 5.0
RE_THRESHOLD_DEG = 5.0
TE_THRESHOLD_M = 0.05
CONFIDENCE_THRESHOLDS = tuple(k / 10.0 for k in range(10))

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


def score_frame(models: Mapping[str, ObjectModel], instances: Sequence[GroundTruthInstance],
                poses: Sequence[PoseEstimate], camera: CameraIntrinsics) -> list[InstanceScore]:
    """Score each counted instance of a frame against the pose that localises it (or none)."""
    return [score_instance(models[instance.object_name], instance, pose, camera)
            for instance, pose in zip(instances,
                                      poses_for_instances(models, poses, instances, camera))]


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


def summarize_objects(scores: Mapping[str, Sequence[InstanceScore]]) -> dict[str, Any]:
    """Make the report's {'objects': {name: POSE_KEYS}, 'mean'} from {name: [InstanceScore]}."""
    per_object = {name: summarize(s) for name, s in scores.items()}
    return {'objects': per_object, 'mean': mean_over_objects(per_object, POSE_KEYS)}


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


def _finite(value):
    return isinstance(value, (int, float)) and math.isfinite(value)
