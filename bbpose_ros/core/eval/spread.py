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
The per-object spread of the pipeline's poses around the truth, for Detection3D covariance.

Each pose is compared with the ground-truth instance it localises: the nearest instance of
its object in 3D, within one object diameter (farther poses are wrong detections and are
left out), and of that instance's symmetric equivalents the one nearest in rotation. Per
object, a spread is 1.4826 x the median absolute error along each camera axis (the standard
deviation a normal error would have, robust to the few flips a symmetric-looking view
causes); the node scales it by ``confidence_median / confidence``
(``ros.detections.ObjectSpread``).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any, TYPE_CHECKING

import numpy as np

from bbpose_ros.core.eval.metrics import symmetric_ground_truths
from bbpose_ros.core.geometry.rotations import log_so3

if TYPE_CHECKING:
    from bbpose_ros.core.data.bop import GroundTruthInstance
    from bbpose_ros.core.data.models import ObjectModel
    from bbpose_ros.core.pipeline.poses import PoseEstimate

MAD_TO_SIGMA = 1.4826


def pose_errors(pose: PoseEstimate, truths: Sequence[GroundTruthInstance],
                models: Mapping[str, ObjectModel]) -> tuple[np.ndarray, np.ndarray] | None:
    """
    Return (translation error (3,) m, rotation error (3,) rad) of a pose, or None.

    Both in the camera frame: the translation's estimate - truth, the rotation vector of
    R_est R_gt^T. None when no instance of the pose's object lies within one diameter.
    """
    model = models[pose.object_name]
    same = [t for t in truths if t.object_name == pose.object_name]
    if not same:
        return None
    truth = min(same, key=lambda t: np.linalg.norm(t.translation - pose.translation))
    if np.linalg.norm(truth.translation - pose.translation) > model.diameter:
        return None
    rotations, translations = symmetric_ground_truths(truth.rotation, truth.translation,
                                                      model.symmetry_transforms)
    vectors = log_so3(pose.rotation @ np.transpose(rotations, (0, 2, 1)))
    best = int(np.argmin(np.linalg.norm(vectors, axis=1)))
    return pose.translation - translations[best], vectors[best]


def spread_of(errors: Iterable[tuple[np.ndarray, np.ndarray, float]]) -> dict[str, Any]:
    """
    Return one object's spread from (translation error, rotation error, confidence) rows.

    Returns:
        {'sigma_m': (3,) translation spread along the camera's x, y, z, metres,
        'sigma_rad': (3,) rotation spread about them, radians, 'confidence_median', 'n'}.

    """
    rows = list(errors)
    t_err = np.array([r[0] for r in rows]).reshape(-1, 3)
    r_err = np.array([r[1] for r in rows]).reshape(-1, 3)
    return {'sigma_m': [round(float(v), 5) for v in MAD_TO_SIGMA * np.median(abs(t_err), 0)],
            'sigma_rad': [round(float(v), 4)
                          for v in MAD_TO_SIGMA * np.median(abs(r_err), 0)],
            'confidence_median': round(float(np.median([r[2] for r in rows])), 3),
            'n': len(rows)}
