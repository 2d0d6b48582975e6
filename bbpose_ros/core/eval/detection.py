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
2D detection metrics of the pipeline's detector on BOP frames: recall and AP at IoU 0.5.

Boxes are amodal [u_min, v_min, u_max, v_max] in continuous pixels, compared with the
ground-truth ``bbox_obj`` boxes. Per object name, detections are matched greedily by score
(``matching.match_by_score``) to the instances with visible fraction >= ``min_visib``; a
detection that only matches a less visible instance is ignored (neither hit nor false alarm).
Recall is also given over the instances with visible fraction >= 0.3, and how far the
matched boxes are off (``box_errors``): the Bounding Box Equation's depth scales with the
box, so a box's relative size error is its pose's relative depth error. AP is computed over
the detections the detector reports, so its score threshold (the setting
``score_threshold``) cuts the precision-recall curve short.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
import math
from typing import Any, TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from bbpose_ros.core.eval.instance_scores import mean_over_objects
from bbpose_ros.core.eval.matching import DETECTION_IOU, match_by_score
from bbpose_ros.core.eval.tables import format_object_table

if TYPE_CHECKING:
    from bbpose_ros.core.data.bop import BopFrame
    from bbpose_ros.core.pipeline.poses import Detection

VISIB_STRICT = 0.3


def average_precision(scores: npt.ArrayLike, hits: npt.ArrayLike, positives: int) -> float:
    """
    All-point interpolated AP (VOC 2010+ / COCO style) from per-detection results.

    Args:
        scores: (D,) detection scores.
        hits: (D,) bool, True for a detection matched to a counted instance.
        positives: number of counted instances.

    """
    if positives == 0:
        return math.nan
    order = np.argsort(-np.asarray(scores, dtype=float), kind='stable')
    hits = np.asarray(hits, dtype=bool)[order]
    tp, fp = np.cumsum(hits), np.cumsum(~hits)
    recall = tp / positives
    precision = tp / np.maximum(tp + fp, 1)
    precision = np.concatenate([[0.0], precision, [0.0]])
    recall = np.concatenate([[0.0], recall, [recall[-1] if len(recall) else 0.0]])
    precision = np.maximum.accumulate(precision[::-1])[::-1]
    return float(np.sum((recall[1:] - recall[:-1]) * precision[1:]))


def score_detections(frames: Sequence[BopFrame], detections: Sequence[Sequence[Detection]],
                     names: Sequence[str], min_visib: float = 0.1) -> dict[str, Any]:
    """
    Score detections already made, one list of Detection per BopFrame, for the given objects.

    Args:
        frames: BopFrame list.
        detections: list (one per frame, same order) of lists of Detection; detections of
            other objects than ``names`` are ignored.
        names: object names to score.
        min_visib: instances less visible than this are not counted.

    Returns:
        {'detection': {name: {'n', 'recall_iou50', 'ap50', 'n_visib30',
        'recall_iou50_visib30', 'size_error_median', 'side_error_rms'}}, 'mean': the
        figures averaged over the objects where they are defined}. ``n`` counts the
        instances with visible fraction >= ``min_visib``, ``n_visib30`` those >= 0.3; the
        box errors are ``box_errors``' over the matched counted instances; a figure with no
        instance to count is NaN.

    Raises:
        ValueError: not one list of detections per frame.

    """
    if len(detections) != len(frames):
        raise ValueError(f'{len(detections)} lists of detections for {len(frames)} frames')
    found = {n: [] for n in names}       # per counted instance: (visib, hit)
    dets = {n: [] for n in names}        # per detection: (score, hit)
    pairs = {n: [] for n in names}       # per hit: (detected box, true box)
    for frame, frame_detections in zip(frames, detections):
        for name in names:
            _score_object(name, frame_detections, frame.instances, min_visib, found[name],
                          dets[name], pairs[name])
    per_object = {}
    for name in names:
        visib = np.array([v for v, _ in found[name]], dtype=float)
        hit = np.array([h for _, h in found[name]], dtype=bool)
        strict = visib >= VISIB_STRICT
        per_object[name] = {
            'n': int(len(hit)),
            'recall_iou50': float(hit.mean()) if len(hit) else math.nan,
            'ap50': average_precision([s for s, _ in dets[name]],
                                      [h for _, h in dets[name]], len(hit)),
            'n_visib30': int(strict.sum()),
            'recall_iou50_visib30': float(hit[strict].mean()) if strict.any() else math.nan,
            **box_errors([d for d, _ in pairs[name]], [t for _, t in pairs[name]]),
        }
    return {'detection': per_object,
            'mean': mean_over_objects(per_object, ('recall_iou50', 'ap50',
                                                   'recall_iou50_visib30', 'size_error_median',
                                                   'side_error_rms'))}


def box_errors(detected_uv: npt.ArrayLike, true_uv: npt.ArrayLike) -> dict[str, float]:
    """
    How far matched (N, 4) boxes are off their (N, 4) true amodal boxes, relative to size.

    Returns:
        {'size_error_median': the median of sqrt(detected area / true area) - 1 (signed: a
        box too small is negative, and puts the equation's depth too far by about as much),
        'side_error_rms': the root mean square of the four sides' offsets over the true
        box's sqrt(area)}; NaN for no boxes.

    """
    detected = np.asarray(detected_uv, dtype=float).reshape(-1, 4)
    truth = np.asarray(true_uv, dtype=float).reshape(-1, 4)
    if not len(truth):
        return {'size_error_median': math.nan, 'side_error_rms': math.nan}

    def size(boxes):
        return np.sqrt((boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1]))

    sides = (detected - truth) / size(truth)[:, None]
    return {'size_error_median': float(np.median(size(detected) / size(truth) - 1.0)),
            'side_error_rms': float(np.sqrt(np.mean(sides ** 2)))}


DETECTION_COLUMNS = (('n', 'n', '{:d}'), ('recall_iou50', 'recall50', '{:.3f}'),
                     ('ap50', 'AP50', '{:.3f}'), ('n_visib30', 'n_vis30', '{:d}'),
                     ('recall_iou50_visib30', 'recall50_v30', '{:.3f}'),
                     ('size_error_median', 'size_err', '{:+.3f}'),
                     ('side_error_rms', 'side_rms', '{:.3f}'))


def format_detection_report(report: Mapping[str, Any]) -> str:
    """Format the per-object detection table (``score_detections``' dict) with a mean row."""
    return format_object_table(report['detection'], report['mean'], DETECTION_COLUMNS, 13)


def _score_object(name, detections, instances, min_visib, found, dets, pairs):
    """Match one object's detections in a frame; append to ``found``, ``dets``, ``pairs``."""
    mine = [d for d in detections if d.object_name == name]
    truths = [i for i in instances if i.object_name == name]
    matches = match_by_score([d.box_uv for d in mine], [d.score for d in mine],
                             [t.box_uv for t in truths], DETECTION_IOU)
    matched = set(matches[matches >= 0].tolist())
    for k, truth in enumerate(truths):
        if truth.visib_fract >= min_visib:
            found.append((truth.visib_fract, k in matched))
    for detection, match in zip(mine, matches):
        if match >= 0 and truths[match].visib_fract < min_visib:
            continue
        dets.append((detection.score, bool(match >= 0)))
        if match >= 0:
            pairs.append((detection.box_uv, truths[match].box_uv))
