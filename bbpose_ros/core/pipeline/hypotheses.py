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
Choosing among a Q-Net's rotation hypotheses by how well each explains the 2D box and mask.

The Bounding Box Equation has four equations (the box sides) for three unknowns (t). Under
the right rotation one translation makes the object touch all four sides; under a wrong one
(say, an elongated object turned the other way) it cannot, and the equation's residuals
grow. ``HypothesisSelector`` solves the equation for every hypothesis and ranks them by

    log p_h - box_consistency_weight * max_k |side residual_k| / longest box side,

with p_h the network's probability of hypothesis h (softmax of its scores): a weight of 20
trusts a side residual of 5 % of the box as much as a factor e of probability. The default
weight was chosen on held-out synthetic crops, never on the real frames
(docs/experiments.md). Scoring solves use a subsample of each object's hull points, which
changes a residual by far less than the differences between hypotheses.

Where the dense net predicts the detection's amodal mask, ``mask_consistency_weight`` adds
``mask_consistency_weight * IoU_h``: the soft IoU of hypothesis h's silhouette (at the
equation's translation) with that mask (``mask_agreement``), which tells apart rotations
whose boxes look alike but whose shapes do not.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from bbpose_ros.core.geometry.bbox_equation import pad_point_sets, solve_translations
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.pipeline.mask_agreement import MaskAgreement
from bbpose_ros.core.pipeline.poses import Detection, RotationHypotheses
from bbpose_ros.core.refine.foreground_masks import ForegroundMasks
from bbpose_ros.core.util.errors import InputError

if TYPE_CHECKING:
    from bbpose_ros.core.data.models import ObjectModel

SCORING_POINTS = 128


def farthest_points(points: npt.ArrayLike, count: int) -> np.ndarray:
    """Pick ``count`` of the (M, 3) points spread over the set (greedy farthest-point order)."""
    points = np.asarray(points, dtype=float)
    if len(points) <= count:
        return points
    chosen = [0]
    distance = np.linalg.norm(points - points[0], axis=1)
    for _ in range(count - 1):
        chosen.append(int(distance.argmax()))
        distance = np.minimum(distance, np.linalg.norm(points - points[chosen[-1]], axis=1))
    return points[chosen]


def box_misfit(side_residuals_px: np.ndarray, boxes_uv: np.ndarray) -> np.ndarray:
    """(N,) largest absolute side residual over the longest side of each (N, 4) box."""
    sides = np.maximum(boxes_uv[:, 2] - boxes_uv[:, 0], boxes_uv[:, 3] - boxes_uv[:, 1])
    return np.abs(side_residuals_px).max(axis=1) / np.maximum(sides, 1e-9)


class HypothesisSelector:
    """
    Pick one rotation per detection from RotationHypotheses.

    Args:
        models: {name: ObjectModel}.
        options: the PipelineOptions: ``box_consistency_weight`` (0, with no mask term,
            keeps the network's best-scored hypothesis and solves nothing) and
            ``mask_consistency_weight``, which counts where masks are given and there is an
            ``agreement``.
        agreement: the MaskAgreement that scores silhouettes against masks; None: no mask
            term.
        points_per_object: hull points kept for the scoring solves.

    Raises:
        InputError: on a call, hypotheses or masks that do not match the detections.

    """

    def __init__(self, models: Mapping[str, ObjectModel], options: PipelineOptions,
                 agreement: MaskAgreement | None = None,
                 points_per_object: int = SCORING_POINTS) -> None:
        self.options = options
        self.agreement = agreement
        self._index = {name: k for k, name in enumerate(models)}
        scored = options.box_consistency_weight > 0.0 or self._mask_term
        self._points = None if not scored else \
            pad_point_sets([farthest_points(m.hull_points, points_per_object)
                            for m in models.values()])

    @property
    def _mask_term(self) -> bool:
        """Tell whether silhouettes are scored against given masks."""
        return self.agreement is not None and self.options.mask_consistency_weight > 0.0

    def __call__(self, camera: CameraIntrinsics, detections: Sequence[Detection],
                 hypotheses: RotationHypotheses) -> np.ndarray:
        """(N, 3, 3) the chosen rotation of each of the N detections."""
        return self.ranked(camera, detections, hypotheses, 1)[:, 0]

    def ranked(self, camera: CameraIntrinsics, detections: Sequence[Detection],
               hypotheses: RotationHypotheses, count: int,
               masks: ForegroundMasks | None = None) -> np.ndarray:
        """
        (N, K, 3, 3) the K = min(count, H) best rotations of each detection, best first.

        ``masks``: the N detections' predicted amodal masks, or None (no mask term).
        """
        rotations, log_probs = hypotheses.rotations, hypotheses.log_probs
        n, total = rotations.shape[:2]
        if log_probs.shape != (n, total) or n != len(detections):
            raise InputError(f'rotation hypotheses {rotations.shape[:2]} with log-probabilities '
                             f'{log_probs.shape} for {len(detections)} detections')
        if masks is not None and len(masks.probabilities) != n:
            raise InputError(f'{len(masks.probabilities)} masks for {n} detections')
        box_weight = self.options.box_consistency_weight
        with_masks = masks is not None and self._mask_term
        ranking = log_probs
        if n > 0 and total > 1 and (box_weight > 0.0 or with_masks):
            boxes = np.repeat(np.stack([d.box_uv for d in detections]).astype(float), total,
                              axis=0)
            points = self._points[[self._index[d.object_name] for d in detections]]
            solution = solve_translations(rotations.reshape(-1, 3, 3), boxes,
                                          np.repeat(points, total, axis=0),
                                          camera.fx, camera.fy, camera.cx, camera.cy)
            misfit = box_misfit(solution.side_residuals_px, boxes).reshape(n, total)
            ranking = log_probs - box_weight * misfit
            if with_masks:
                each = np.repeat(np.arange(n), total)
                agreement = self.agreement(camera, [detections[k].object_name for k in each],
                                           rotations.reshape(-1, 3, 3), solution.translations,
                                           masks.take(each))
                ranking = ranking + self.options.mask_consistency_weight * \
                    agreement.reshape(n, total)
        order = np.argsort(-ranking, axis=1, kind='stable')[:, :max(1, min(count, total))]
        return rotations[np.arange(n)[:, None], order]
