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

Poses come stacked: rotations (N, 3, 3), translations (N, 3) metres, covariances (N, 3, 3)
square metres, weights (N,) and view groups (N,) int, one view's candidates consecutive.
The loops are compiled (numba): a map refits an object at every view it takes.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numba
import numpy as np

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


@numba.njit(cache=True, nogil=True)
def _closest_copy(reference, rotation, symmetry_r):
    """Index of the symmetry S making rotation @ S closest to ``reference``, and its trace."""
    best, best_trace = 0, -np.inf
    for s in range(symmetry_r.shape[0]):
        trace = 0.0
        for a in range(3):
            for b in range(3):
                rs = 0.0
                for c in range(3):
                    rs += rotation[a, c] * symmetry_r[s, c, b]
                trace += reference[a, b] * rs
        if trace > best_trace:
            best, best_trace = s, trace
    return best, best_trace


@numba.njit(cache=True, nogil=True)
def _aligned(rotation, translation, symmetry_r, symmetry_t, s):
    """Return the pose (R @ S_R, R @ S_t + t) of symmetry ``s``."""
    return rotation @ symmetry_r[s], translation + rotation @ symmetry_t[s]


@numba.njit(cache=True, nogil=True)
def _mahalanobis2(delta, covariance):
    return delta @ np.linalg.solve(covariance, delta)


@numba.njit(cache=True, nogil=True)
def _agreement(rotations_a, translations_a, covariances_a, rotations_b, translations_b,
               covariances_b, symmetry_r, symmetry_t, min_trace, chi2):
    agree = np.zeros((rotations_a.shape[0], rotations_b.shape[0]), dtype=np.bool_)
    for i in range(rotations_a.shape[0]):
        for j in range(rotations_b.shape[0]):
            s, trace = _closest_copy(rotations_a[i], rotations_b[j], symmetry_r)
            if trace < min_trace:
                continue
            _, aligned_t = _aligned(rotations_b[j], translations_b[j], symmetry_r, symmetry_t, s)
            agree[i, j] = _mahalanobis2(translations_a[i] - aligned_t,
                                        covariances_a[i] + covariances_b[j]) < chi2
    return agree


def agreement(rotations_a: np.ndarray, translations_a: np.ndarray, covariances_a: np.ndarray,
              rotations_b: np.ndarray, translations_b: np.ndarray, covariances_b: np.ndarray,
              symmetries: np.ndarray, gate_deg: float) -> np.ndarray:
    """Return (A, B) bool: which poses of set a agree with which of set b (module doc)."""
    return _agreement(rotations_a, translations_a, covariances_a, rotations_b, translations_b,
                      covariances_b, np.ascontiguousarray(symmetries[:, :3, :3]),
                      np.ascontiguousarray(symmetries[:, :3, 3]), _min_trace(gate_deg),
                      CHI2_3DOF_99)


def _min_trace(gate_deg):
    """Return the trace of R_a^T R_b at which the angle between them reaches the gate."""
    return 1.0 + 2.0 * math.cos(math.radians(gate_deg))


@numba.njit(cache=True, nogil=True)
def _one_a_view(candidates, weights, groups):
    """(N,) bool: of the ``candidates`` (N,) bool, the most confident of each view group."""
    chosen = np.zeros(candidates.shape[0], dtype=np.bool_)
    k = 0
    while k < groups.shape[0]:
        end, best = k, -1
        while end < groups.shape[0] and groups[end] == groups[k]:
            if candidates[end] and (best < 0 or weights[end] > weights[best]):
                best = end
            end += 1
        if best >= 0:
            chosen[best] = True
        k = end
    return chosen


@numba.njit(cache=True, nogil=True)
def _fuse(rotations, translations, covariances, weights, chosen, reference, symmetry_r,
          symmetry_t):
    """Fuse the chosen poses aligned to ``reference``: rotation, translation, covariance."""
    mean_r = np.zeros((3, 3))
    weighted, information, pull = np.zeros((3, 3)), np.zeros((3, 3)), np.zeros(3)
    for n in range(rotations.shape[0]):
        if not chosen[n]:
            continue
        s, _ = _closest_copy(reference, rotations[n], symmetry_r)
        aligned_r, aligned_t = _aligned(rotations[n], translations[n], symmetry_r, symmetry_t,
                                        s)
        mean_r += weights[n] * aligned_r
        inverse = np.linalg.inv(covariances[n])
        information += inverse
        weighted += weights[n] * inverse
        pull += weights[n] * (inverse @ aligned_t)
    u, _, vt = np.linalg.svd(mean_r)
    flip = np.eye(3)
    flip[2, 2] = np.sign(np.linalg.det(u @ vt))
    return u @ flip @ vt, np.linalg.solve(weighted, pull), np.linalg.inv(information)


@numba.njit(cache=True, nogil=True)
def _consensus(rotations, translations, covariances, weights, groups, agree, symmetry_r,
               symmetry_t, min_trace, chi2):
    count = rotations.shape[0]
    best_support, seed = -1.0, 0
    for i in range(count):
        support, k = 0.0, 0
        while k < count:                    # each view adds its best agreeing weight
            end, best = k, 0.0
            while end < count and groups[end] == groups[k]:
                if agree[i, end] and (groups[end] != groups[i] or end == i):
                    best = max(best, weights[end])
                end += 1
            support += best
            k = end
        if support >= best_support:         # ties: the newest view
            best_support, seed = support, i
    candidates = agree[seed].copy()
    for n in range(count):
        if groups[n] == groups[seed] and n != seed:
            candidates[n] = False
    chosen = _one_a_view(candidates, weights, groups)
    rotation, translation, covariance = _fuse(rotations, translations, covariances, weights,
                                              chosen, rotations[seed], symmetry_r, symmetry_t)
    agreeing = np.zeros(count, dtype=np.bool_)
    for n in range(count):
        s, trace = _closest_copy(rotation, rotations[n], symmetry_r)
        if trace >= min_trace:
            _, aligned_t = _aligned(rotations[n], translations[n], symmetry_r, symmetry_t, s)
            agreeing[n] = _mahalanobis2(aligned_t - translation,
                                        covariances[n] + covariance) < chi2
    if agreeing.any():
        chosen = _one_a_view(agreeing, weights, groups)
        rotation, translation, covariance = _fuse(rotations, translations, covariances,
                                                  weights, chosen, rotation, symmetry_r,
                                                  symmetry_t)
    return rotation, translation, covariance, chosen, np.linalg.eigvalsh(covariance)[-1]


def fuse_views(rotations: np.ndarray, translations: np.ndarray, covariances: np.ndarray,
               weights: np.ndarray, groups: np.ndarray, agree: np.ndarray,
               symmetries: np.ndarray, gate_deg: float, tolerance_m: float,
               previous: FusedPose | None = None) -> FusedPose:
    """
    Fuse an object's views' candidate poses into one pose (see the module docstring).

    The poses are stacked as the module docstring says; ``agree``: (N, N) their
    ``agreement`` with each other (kept by the caller, which adds and drops views);
    ``tolerance_m``: the translation error the confidence is the chance of staying within
    (the object's ADD(-S) threshold, a tenth of its diameter). ``previous``: the pose fused
    before, if any: a symmetric object keeps the symmetric copy of the new pose nearest it,
    so that its map pose does not flip between equivalent poses from refit to refit.
    """
    symmetry_r = np.ascontiguousarray(symmetries[:, :3, :3])
    symmetry_t = np.ascontiguousarray(symmetries[:, :3, 3])
    rotation, translation, covariance, inliers, worst_variance = _consensus(
        rotations, translations, covariances, weights, groups, agree, symmetry_r, symmetry_t,
        _min_trace(gate_deg), CHI2_3DOF_99)
    if previous is not None:
        s, _ = _closest_copy(previous.rotation, rotation, symmetry_r)
        rotation, translation = _aligned(rotation, translation, symmetry_r, symmetry_t, s)
    worst_sigma = math.sqrt(max(float(worst_variance), 1e-12))
    within = math.erf(tolerance_m / (math.sqrt(2.0) * worst_sigma))
    return FusedPose(rotation, translation, covariance, inliers,
                     float(np.mean(weights[inliers]) * within))
