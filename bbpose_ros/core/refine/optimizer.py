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
The optimizer: damped Newton steps on the 6-DoF pose from the modalities' pulls.

A modality gives, per pose, a gradient (N, 6) and a Gauss-Newton Hessian (N, 6, 6) over
the increment (theta_r, theta_t): a rotation vector and a translation, both in the model
frame, x' = exp(theta_r) x + theta_t. Tikhonov damping (per radian squared and per metre
squared) keeps every step solvable, also for a pose without a single line, and bounds it.
A start prior (``start_prior``) adds what the start itself says of the pose: a Gaussian
around it, so that directions the lines hardly constrain stay where they started instead of
drifting with the lines' noise over many steps.
"""

import math

import numba
import numpy as np

from bbpose_ros.core.geometry.rotations import log_so3


@numba.njit(cache=True, nogil=True)
def _newton_update(rotation, translation, gradient, hessian, damping, moving):
    """Solve (H + diag(damping)) theta = g by Cholesky and move each ``moving`` pose."""
    a = np.empty((6, 6))
    for n in range(rotation.shape[0]):
        if not moving[n]:
            continue
        for i in range(6):
            for j in range(6):
                a[i, j] = hessian[n, i, j]
            a[i, i] += damping[i]
        for j in range(6):          # A = L L^T, L in the lower triangle of a
            for k in range(j):
                a[j, j] -= a[j, k] * a[j, k]
            a[j, j] = math.sqrt(a[j, j])
            for i in range(j + 1, 6):
                for k in range(j):
                    a[i, j] -= a[i, k] * a[j, k]
                a[i, j] /= a[j, j]
        theta = gradient[n].copy()
        for i in range(6):
            for k in range(i):
                theta[i] -= a[i, k] * theta[k]
            theta[i] /= a[i, i]
        for i in range(5, -1, -1):
            for k in range(i + 1, 6):
                theta[i] -= a[k, i] * theta[k]
            theta[i] /= a[i, i]
        # exp of the rotation vector (Rodrigues), then R' = R dR and t' = t + R dt.
        wx, wy, wz = theta[0], theta[1], theta[2]
        angle = math.sqrt(wx * wx + wy * wy + wz * wz)
        if angle > 1e-12:
            s, c = math.sin(angle) / angle, (1.0 - math.cos(angle)) / (angle * angle)
        else:
            s, c = 1.0, 0.5
        step = np.array([[1.0 - c * (wy * wy + wz * wz), c * wx * wy - s * wz,
                          c * wx * wz + s * wy],
                         [c * wx * wy + s * wz, 1.0 - c * (wx * wx + wz * wz),
                          c * wy * wz - s * wx],
                         [c * wx * wz - s * wy, c * wy * wz + s * wx,
                          1.0 - c * (wx * wx + wy * wy)]])
        before = rotation[n].copy()
        for i in range(3):
            translation[n, i] += (before[i, 0] * theta[3] + before[i, 1] * theta[4]
                                  + before[i, 2] * theta[5])
            for j in range(3):
                rotation[n, i, j] = (before[i, 0] * step[0, j] + before[i, 1] * step[1, j]
                                     + before[i, 2] * step[2, j])


def newton_update(rotation: np.ndarray, translation: np.ndarray, gradient: np.ndarray,
                  hessian: np.ndarray, tikhonov_rotation: float, tikhonov_translation: float,
                  moving: np.ndarray) -> None:
    """
    Take one damped Newton step for the ``moving`` poses, in place: R' = R dR, t' = t + R dt.

    The step theta = (H + damping)^-1 g is a rotation vector dr (dR = exp(dr)) and a
    model-frame shift dt; compiled (numba), as it runs twice a correspondence iteration.

    Args:
        rotation: (N, 3, 3) model-to-camera rotations (float64, C order), updated.
        translation: (N, 3) translations, metres, updated.
        gradient: (N, 6) gradients, rotation first.
        hessian: (N, 6, 6) Hessians (positive semi-definite; not modified).
        tikhonov_rotation: damping of the rotation, per radian squared, > 0.
        tikhonov_translation: damping of the translation, per metre squared, > 0.
        moving: (N,) bool which poses move.

    """
    damping = np.array([tikhonov_rotation] * 3 + [tikhonov_translation] * 3)
    _newton_update(rotation, translation, np.ascontiguousarray(gradient, dtype=float),
                   np.ascontiguousarray(hessian, dtype=float), damping, moving)


def start_prior(gradient: np.ndarray, hessian: np.ndarray, rotation: np.ndarray,
                translation: np.ndarray, start_rotation: np.ndarray,
                start_translation: np.ndarray, prior_rotation: float,
                prior_translation: float) -> tuple[np.ndarray, np.ndarray]:
    """
    Add a Gaussian prior around the start poses to N poses' gradients and Hessians.

    The prior's information is ``prior_rotation`` per radian squared and
    ``prior_translation`` per metre squared (1 / its variance), in the increment's model
    frame: it pulls each pose back towards its start with the force of its distance.

    Args:
        gradient: (N, 6) gradients, rotation first.
        hessian: (N, 6, 6) Hessians.
        rotation, translation: (N, 3, 3), (N, 3) current poses (metres).
        start_rotation, start_translation: (N, 3, 3), (N, 3) their starts.
        prior_rotation: information of the rotation prior, per radian squared, >= 0.
        prior_translation: information of the translation prior, per metre squared, >= 0.

    Returns:
        ((N, 6) gradients, (N, 6, 6) Hessians) with the prior (new arrays).

    """
    back_rotation = log_so3(rotation.transpose(0, 2, 1) @ start_rotation)
    back_translation = ((start_translation - translation)[:, None, :] @ rotation)[:, 0]
    information = np.array([prior_rotation] * 3 + [prior_translation] * 3)
    return (gradient + information * np.concatenate([back_rotation, back_translation], axis=1),
            hessian + np.diag(information))
