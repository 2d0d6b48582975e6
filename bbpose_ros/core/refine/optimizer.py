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

import numpy as np

from bbpose_ros.core.geometry.rotations import exp_so3, log_so3


def newton_step(gradient: np.ndarray, hessian: np.ndarray, tikhonov_rotation: float,
                tikhonov_translation: float) -> tuple[np.ndarray, np.ndarray]:
    """
    Solve the damped Newton step of N poses.

    Args:
        gradient: (N, 6) gradients, rotation first.
        hessian: (N, 6, 6) Hessians (not modified).
        tikhonov_rotation: damping of the rotation, per radian squared, > 0.
        tikhonov_translation: damping of the translation, per metre squared, > 0.

    Returns:
        ((N, 3, 3) rotation increments exp(theta_r), (N, 3) model-frame shifts theta_t).

    """
    damped = hessian + np.diag([tikhonov_rotation] * 3 + [tikhonov_translation] * 3)
    theta = np.linalg.solve(damped, gradient[..., None])[..., 0]
    return exp_so3(theta[:, :3]), theta[:, 3:]


def apply_step(rotation: np.ndarray, translation: np.ndarray, step_rotation: np.ndarray,
               step_translation: np.ndarray, moving: np.ndarray) -> None:
    """
    Move the ``moving`` (N,) bool poses by their steps, in place: R' = R dR, t' = t + R dt.

    Args:
        rotation: (N, 3, 3) model-to-camera rotations.
        translation: (N, 3) translations, metres.
        step_rotation: (N, 3, 3) rotation increments, from ``newton_step``.
        step_translation: (N, 3) model-frame shifts, from ``newton_step``.
        moving: (N,) which poses move.

    """
    before = rotation[moving]
    rotation[moving] = before @ step_rotation[moving]
    translation[moving] += (before @ step_translation[moving][..., None])[..., 0]


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
