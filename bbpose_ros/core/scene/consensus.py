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
Fusing the views of one object: which views agree, and the pose they agree on.

A view may offer several candidate poses (the pipeline's chosen pose and its other refined
candidates, ``PoseEstimate.alternatives``); each view gives at most one of them to the
consensus. Two candidates of different views agree when their rotations are within
``map_gate_deg`` of each other (for a symmetric object, under the symmetry that brings them
closest) and their translations within the 99 % ellipsoid of their summed covariances
(``views.ray_covariance``). The candidate the most views agree with, each view counting its
most confident agreeing candidate, seeds a consensus; those agreeing candidates are fused:
translations by their information (inverse covariance) matrices, so rays from different
directions intersect, rotations by their confidence-weighted chordal mean. The candidates
agreeing with that fused pose (again one a view) are fused once more.

Symmetry transforms are (S, 4, 4), identity first (``ObjectModel.symmetry_transforms``):
a pose (R, t) equals (R @ S_R, R @ S_t + t) for each.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math

import numpy as np

from bbpose_ros.core.geometry.rotations import nearest_rotation
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.scene.views import ViewedPose

# The 99 % quantile of chi-square with 3 degrees of freedom: a translation gate.
CHI2_3DOF_99 = 11.345


@dataclass(frozen=True)
class FusedPose:
    """
    The pose a set of views agrees on, in the fixed frame.

    Attributes:
        rotation: (3, 3) model-to-world rotation.
        translation: (3,) metres.
        covariance: (3, 3) the translation's covariance, square metres (the inverse of the
            inliers' summed information).
        inliers: (N,) bool over the views fused: those that agree with the pose.
        confidence: 0..1, the inliers' mean confidence times the chance that the
            translation's worst axis is within ``tolerance_m`` (see ``fuse_views``).

    """

    rotation: np.ndarray
    translation: np.ndarray
    covariance: np.ndarray
    inliers: np.ndarray
    confidence: float


def _stack(views, symmetries):
    rotations = np.array([v.rotation for v in views])
    translations = np.array([v.translation for v in views])
    covariances = np.array([v.covariance for v in views])
    weights = np.array([max(v.confidence, 1e-3) for v in views])
    return rotations, translations, covariances, weights


def _symmetric_copies(rotations, translations, symmetries):
    """(N, S, 3, 3) rotations and (N, S, 3) translations of each view under each symmetry."""
    copies_r = np.einsum('nab,sbc->nsac', rotations, symmetries[:, :3, :3])
    copies_t = translations[:, None] + np.einsum('nab,sb->nsa', rotations, symmetries[:, :3, 3])
    return copies_r, copies_t


def _closest(reference_r, copies_r):
    """For each (N, S) copy set, the copy closest to (3, 3) ``reference_r``: indices, deg."""
    traces = np.einsum('ab,nsab->ns', reference_r, copies_r)
    best = np.argmax(traces, axis=1)
    cosine = np.clip((traces[np.arange(len(best)), best] - 1.0) / 2.0, -1.0, 1.0)
    return best, np.degrees(np.arccos(cosine))


def _mahalanobis2(delta, covariance):
    """(...,) squared Mahalanobis lengths of (..., 3) vectors under (..., 3, 3) covariances."""
    return np.einsum('...a,...a->...', delta, np.linalg.solve(covariance, delta[..., None])[..., 0])


def agreement(views_a: Sequence[ViewedPose], views_b: Sequence[ViewedPose],
              symmetries: np.ndarray, options: PipelineOptions) -> np.ndarray:
    """(A, B) bool: which poses of ``views_a`` agree with which of ``views_b`` (module doc)."""
    if not views_a or not views_b:
        return np.zeros((len(views_a), len(views_b)), dtype=bool)
    rotations_a, translations_a, covariances_a, _ = _stack(views_a, symmetries)
    rotations_b, translations_b, covariances_b, _ = _stack(views_b, symmetries)
    copies_r, copies_t = _symmetric_copies(rotations_b, translations_b, symmetries)
    traces = np.einsum('iab,jsab->ijs', rotations_a, copies_r)
    best = np.argmax(traces, axis=2)
    angle = np.degrees(np.arccos(np.clip((np.take_along_axis(traces, best[..., None], 2)[..., 0]
                                           - 1.0) / 2.0, -1.0, 1.0)))
    aligned_t = copies_t[np.arange(len(views_b))[None], best]
    delta = translations_a[:, None] - aligned_t
    distance2 = _mahalanobis2(delta, covariances_a[:, None] + covariances_b[None])
    return (angle < options.map_gate_deg) & (distance2 < CHI2_3DOF_99)


def _fuse(rotations, translations, covariances, weights, reference_r, symmetries):
    """Fuse views aligned to ``reference_r`` under their closest symmetry: R, t, covariance."""
    copies_r, copies_t = _symmetric_copies(rotations, translations, symmetries)
    best, _ = _closest(reference_r, copies_r)
    index = np.arange(len(best))
    aligned_r, aligned_t = copies_r[index, best], copies_t[index, best]
    rotation = nearest_rotation(np.einsum('n,nab->ab', weights, aligned_r))
    information = np.linalg.inv(covariances)
    weighted = weights[:, None, None] * information
    translation = np.linalg.solve(weighted.sum(0), np.einsum('nab,nb->a', weighted, aligned_t))
    return rotation, translation, np.linalg.inv(information.sum(0))


def _one_a_view(candidates, weights, groups):
    """(N,) bool: of the ``candidates`` (N,) bool, the most confident of each view group."""
    score = np.where(candidates, weights, -1.0)
    best = np.zeros(len(groups), dtype=bool)
    for view in np.unique(groups[candidates]):
        members = np.flatnonzero(groups == view)
        best[members[np.argmax(score[members])]] = True
    return best


def fuse_views(views: Sequence[ViewedPose], agree: np.ndarray, symmetries: np.ndarray,
               options: PipelineOptions, tolerance_m: float) -> FusedPose:
    """
    Fuse an object's views' candidate poses into one pose (see the module docstring).

    ``views``: the candidates, those of one view consecutive and sharing its ``view``;
    ``agree``: (N, N) their ``agreement`` with each other (kept by the caller, which adds
    and drops views); ``tolerance_m``: the translation error the confidence is the chance
    of staying within (the object's ADD(-S) threshold, a tenth of its diameter).
    """
    rotations, translations, covariances, weights = _stack(views, symmetries)
    groups = np.array([v.view for v in views])
    agree = agree & ((groups[:, None] != groups[None]) | np.eye(len(views), dtype=bool))
    starts = np.flatnonzero(np.r_[True, groups[1:] != groups[:-1]])
    support = np.maximum.reduceat(agree * weights[None], starts, axis=1).sum(1)
    seed = int(np.flatnonzero(support == support.max())[-1])     # ties: the newest view
    inliers = _one_a_view(agree[seed], weights, groups)
    rotation, translation, covariance = _fuse(
        rotations[inliers], translations[inliers], covariances[inliers], weights[inliers],
        rotations[seed], symmetries)
    copies_r, copies_t = _symmetric_copies(rotations, translations, symmetries)
    best, angle = _closest(rotation, copies_r)
    delta = copies_t[np.arange(len(views)), best] - translation
    agreeing = (angle < options.map_gate_deg) & \
        (_mahalanobis2(delta, covariances + covariance) < CHI2_3DOF_99)
    if agreeing.any():
        inliers = _one_a_view(agreeing, weights, groups)
        rotation, translation, covariance = _fuse(
            rotations[inliers], translations[inliers], covariances[inliers],
            weights[inliers], rotation, symmetries)
    worst_sigma = math.sqrt(max(float(np.linalg.eigvalsh(covariance)[-1]), 1e-12))
    within = math.erf(tolerance_m / (math.sqrt(2.0) * worst_sigma))
    return FusedPose(rotation, translation, covariance, inliers,
                     float(np.mean(weights[inliers]) * within))
