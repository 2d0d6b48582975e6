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
A pose from a crop's dense correspondences: PnP with RANSAC over the masked cells (OpenCV).

Each cell (i, j) of the dense maps pairs the full-frame pixel of its centre
(``dense_grid.cell_centres_uv``) with the model point of its predicted normalised
coordinates (``box_min + c * box_size``, metres). EPnP inside RANSAC gives the inliers,
Levenberg-Marquardt on the inliers the pose.
"""

from dataclasses import dataclass

import cv2
import numpy as np

from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.dense_grid import cell_centres_uv

# Fewest cells PnP is tried on (EPnP needs 4; RANSAC wants some to spare).
MIN_POINTS = 6


@dataclass(frozen=True)
class DensePose:
    """
    What ``pose_from_dense_maps`` found.

    Attributes:
        rotation: (3, 3) egocentric model-to-camera rotation.
        translation: (3,) metres, camera frame.
        inliers: count of cells within the reprojection threshold.
        points: count of masked cells PnP was given.

    """

    rotation: np.ndarray
    translation: np.ndarray
    inliers: int
    points: int


def pose_from_dense_maps(coordinates: np.ndarray, mask_probability: np.ndarray,
                         square_uv: np.ndarray, camera: CameraIntrinsics,
                         box_min: np.ndarray, box_size: np.ndarray,
                         mask_threshold: float = 0.5, reprojection_cells: float = 1.5,
                         iterations: int = 50) -> DensePose | None:
    """
    Solve the pose of one crop from its predicted maps; None with too few masked cells.

    Args:
        coordinates: (M, M, 3) predicted normalised model coordinates.
        mask_probability: (M, M) predicted visible-mask probability (0..1).
        square_uv: (4,) the crop's square in full-frame continuous pixels.
        camera: the full frame's CameraIntrinsics.
        box_min: (3,) corner of the model box of the normalisation, metres.
        box_size: (3,) size of that box, metres.
        mask_threshold: cells above this probability are used.
        reprojection_cells: RANSAC inlier threshold in cells (full-frame pixels / cell side).
        iterations: RANSAC's most iterations (it stops sooner once 99 % sure); each costs an
            EPnP solve and a reprojection of every cell, most of the stage's time.

    """
    size = coordinates.shape[0]
    chosen = mask_probability > mask_threshold
    points = int(np.count_nonzero(chosen))
    if points < MIN_POINTS:
        return None
    image_points = cell_centres_uv(np.asarray(square_uv, dtype=float), size)[chosen]
    model_points = np.asarray(box_min) + coordinates[chosen].astype(np.float64) * box_size
    cell_px = (square_uv[2] - square_uv[0]) / size
    found, rvec, tvec, inliers = cv2.solvePnPRansac(
        model_points, image_points, camera.k, None, iterationsCount=iterations,
        reprojectionError=float(reprojection_cells * cell_px), confidence=0.99,
        flags=cv2.SOLVEPNP_EPNP)
    if not found or inliers is None or len(inliers) < 4:
        return None
    inliers = inliers[:, 0]
    rvec, tvec = cv2.solvePnPRefineLM(model_points[inliers], image_points[inliers], camera.k,
                                      None, rvec, tvec)
    rotation, _ = cv2.Rodrigues(rvec)
    return DensePose(rotation, tvec.ravel(), len(inliers), points)
