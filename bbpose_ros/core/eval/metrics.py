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
Pose error functions, in agreement with bop_toolkit ``pose_error.py``.

Each function scores one estimated pose (R_e, t_e) against the ground truth (R_g, t_g):
R (3, 3) model-to-camera, t (3,) in metres, model points ``pts`` (P, 3) in metres.
Thresholds follow BOP: ADD(-S) < 0.1 diameter, projection < 5 px, 5 cm / 5 degrees.
"""

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from bbpose_ros.core.geometry.projection import project_with_k, transform_points
from bbpose_ros.core.geometry.rotations import rotation_error_deg


def add(rotation_e: npt.ArrayLike, t_e: npt.ArrayLike, rotation_g: npt.ArrayLike,
        t_g: npt.ArrayLike, pts: np.ndarray) -> float:
    """Average Distance of model points (ADD, Hinterstoisser 2012), metres."""
    est = transform_points(pts, rotation_e, t_e)
    gt = transform_points(pts, rotation_g, t_g)
    return float(np.linalg.norm(est - gt, axis=1).mean())


def adi(rotation_e: npt.ArrayLike, t_e: npt.ArrayLike, rotation_g: npt.ArrayLike,
        t_g: npt.ArrayLike, pts: np.ndarray) -> float:
    """Compute ADD-S: mean distance of each true point to the closest estimated one, metres."""
    est = transform_points(pts, rotation_e, t_e)
    gt = transform_points(pts, rotation_g, t_g)
    distances, _ = cKDTree(est).query(gt, k=1)
    return float(distances.mean())


def proj(rotation_e: npt.ArrayLike, t_e: npt.ArrayLike, rotation_g: npt.ArrayLike,
         t_g: npt.ArrayLike, k: npt.ArrayLike, pts: np.ndarray) -> float:
    """Mean 2D distance of the projected model points (pixels) under the 3x3 camera K."""
    est = project_with_k(transform_points(pts, rotation_e, t_e), k)
    gt = project_with_k(transform_points(pts, rotation_g, t_g), k)
    return float(np.linalg.norm(est - gt, axis=1).mean())


def re(rotation_e: npt.ArrayLike, rotation_g: npt.ArrayLike) -> float:
    """Rotation error in degrees: the angle of R_e R_g^T."""
    return float(rotation_error_deg(rotation_e, rotation_g))


def te(t_e: npt.ArrayLike, t_g: npt.ArrayLike) -> float:
    """Compute the translation error, metres."""
    return float(np.linalg.norm(np.asarray(t_e) - np.asarray(t_g)))


def symmetric_ground_truths(rotation_g: npt.ArrayLike, t_g: npt.ArrayLike,
                            symmetry_transforms: npt.ArrayLike
                            ) -> tuple[np.ndarray, np.ndarray]:
    """
    All poses equivalent to the ground truth under the (S, 4, 4) symmetry transforms.

    Returns (S, 3, 3) rotations and (S, 3) translations: R_g S_R and t_g + R_g S_t.
    """
    sym = np.asarray(symmetry_transforms)
    rotations = np.asarray(rotation_g) @ sym[:, :3, :3]
    translations = np.asarray(t_g) + sym[:, :3, 3] @ np.asarray(rotation_g).T
    return rotations, translations


def cm_deg_errors(rotation_e: npt.ArrayLike, t_e: npt.ArrayLike, rotation_g: npt.ArrayLike,
                  t_g: npt.ArrayLike, symmetry_transforms: npt.ArrayLike) -> tuple[float, float]:
    """
    (re in degrees, te in metres) against the closest symmetric equivalent of the truth.

    For an object without symmetries pass ``np.eye(4)[None]``; this is then plain re, te.
    The equivalent with the smallest rotation error is chosen.
    """
    rotations, translations = symmetric_ground_truths(rotation_g, t_g, symmetry_transforms)
    errors = rotation_error_deg(np.asarray(rotation_e)[None], rotations)
    best = int(np.argmin(errors))
    return float(errors[best]), te(t_e, translations[best])


def recall(errors: npt.ArrayLike, threshold: float) -> float:
    """Fraction of errors below ``threshold``; a missed estimate (NaN) counts as a failure."""
    errors = np.asarray(errors, dtype=float)
    if errors.size == 0:
        return float('nan')
    return float(np.mean(np.where(np.isnan(errors), False, errors < threshold)))
