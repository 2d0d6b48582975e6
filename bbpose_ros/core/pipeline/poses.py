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
The values the pipeline's stages hand on: detections, rotation hypotheses, poses, frames.

A leaf module (numpy only): every stage, the tracker, the evaluation and the ROS adapter
import these types from here, so no stage depends on the one that orchestrates them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SOURCES = ('qnet', 'pnp', 'pnp_rotation', 'given', 'map')


@dataclass(frozen=True)
class Detection:
    """
    A 2D detection of one object.

    Attributes:
        object_name: e.g. 'ape'.
        score: detector confidence, 0..1 (1 for ground truth).
        box_uv: (4,) amodal box [u_min, v_min, u_max, v_max], continuous pixel coordinates
            (pixel centres at integers), the outer edges of the whole object's projection.

    """

    object_name: str
    score: float
    box_uv: np.ndarray


@dataclass(frozen=True)
class RotationHypotheses:
    """
    Several candidate rotations per detection.

    Attributes:
        rotations: (N, H, 3, 3) egocentric model-to-camera rotations.
        log_probs: (N, H) log-probabilities the network gives them (log-softmax of scores).

    """

    rotations: np.ndarray
    log_probs: np.ndarray


@dataclass(frozen=True)
class PoseEstimate:
    """
    A 6D pose: x_cam = rotation @ x_model + translation.

    Attributes:
        detection: the Detection it was estimated from.
        rotation: (3, 3) model-to-camera rotation (egocentric).
        translation: (3,) metres, camera optical frame.
        refinement_score: when refined, the share of contour lines that agree with the
            image (0..1, ``refine.region_modality``); None when not refined.
        source: where the pose started, one of SOURCES: 'qnet' (a Q-Net rotation and the
            Bounding Box Equation, the paper's path), 'pnp' (PnP over the dense
            correspondences, rotation and translation), 'pnp_rotation' (PnP's rotation and
            the Bounding Box Equation's translation), 'given' (rotations handed in: ground
            truth, a track), 'map' (the scene's map, ``core.scene.object_map``).
        alternatives: the detection's other refined candidates, best first, as (rotation
            (3, 3), translation (3,) metres, refinement score) after the screening
            iterations (``PoseRefiner.best_of``): what a map can choose from where views
            disagree; empty when there were none.

    """

    detection: Detection
    rotation: np.ndarray
    translation: np.ndarray
    refinement_score: float | None = None
    source: str = 'qnet'
    alternatives: tuple[tuple[np.ndarray, np.ndarray, float], ...] = ()

    @property
    def object_name(self) -> str:
        """Name of the object."""
        return self.detection.object_name

    @property
    def confidence(self) -> float:
        """Return the refinement score when refined, else the detection score (0..1)."""
        if self.refinement_score is not None:
            return self.refinement_score
        return self.detection.score


@dataclass(frozen=True)
class FrameResult:
    """The poses found in one frame and the time each stage took (milliseconds)."""

    poses: list[PoseEstimate]
    timings_ms: dict[str, float]
