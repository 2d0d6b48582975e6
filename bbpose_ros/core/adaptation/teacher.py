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
The teacher: the most careful pipeline there is, run offline on each unlabelled frame.

Speed does not matter here, so the teacher runs what measured most precise as a judge of
its own poses on the dev frames (docs/training.md, "Adapt to a scene"): the dense net's PnP
poses beside Q-Net's (``pose_source`` dense+qnet), boxes from the detector and from the
dense net's amodal masks (``box_source`` both), every candidate refined, float networks.
Its detector threshold is low: detections it reports but does not trust become regions
the students neither learn from nor learn against (``selection``).

Each found pose is kept with its confidence (the refinement score) and the amodal box its
mesh projects to at that pose: on real frames those boxes are truer in size than the
detector's, which is what the students learn from them.
"""

from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from bbpose_ros.core.data.models import ObjectModel
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.projection import projected_box_uv
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.pipeline.loader import load_pipeline, WeightFiles
from bbpose_ros.core.util.errors import InputError


def teacher_options(base: PipelineOptions, score_threshold: float) -> PipelineOptions:
    """Lay the teacher's careful settings over ``base`` (its backend and threads kept)."""
    return replace(base, score_threshold=score_threshold, max_instances=1, refine=True,
                   pose_source='dense+qnet', box_source='both', tracking=False,
                   inference_precision='fp32', refine_min_score=0.0)


@dataclass(frozen=True)
class TeacherPose:
    """
    One pose the teacher found.

    Attributes:
        object_name: the object.
        detection_score: the detector's score of its detection (0..1).
        detection_box_uv: (4,) the box it was solved from [u_min, v_min, u_max, v_max],
            full-frame continuous pixels (pixel centres at integers).
        rotation: (3, 3) model-to-camera rotation (egocentric).
        translation: (3,) metres, camera optical frame.
        confidence: the refinement score (0..1).
        box_uv: (4,) amodal box of the mesh projected at the pose, same pixels.

    """

    object_name: str
    detection_score: float
    detection_box_uv: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    confidence: float
    box_uv: np.ndarray

    def record(self) -> dict[str, Any]:
        """Return the pose as a JSON-ready dict (``from_record`` reads it back)."""
        return {'object': self.object_name, 'detection_score': self.detection_score,
                'detection_box_uv': self.detection_box_uv.tolist(),
                'rotation': self.rotation.tolist(), 'translation_m': self.translation.tolist(),
                'confidence': self.confidence, 'box_uv': self.box_uv.tolist()}

    @classmethod
    def from_record(cls, record: Mapping[str, Any]) -> 'TeacherPose':
        """Read a ``record`` dict back."""
        return cls(record['object'], float(record['detection_score']),
                   np.array(record['detection_box_uv'], dtype=float),
                   np.array(record['rotation'], dtype=float),
                   np.array(record['translation_m'], dtype=float),
                   float(record['confidence']), np.array(record['box_uv'], dtype=float))


class Teacher:
    """
    Callable ``(image_rgb, camera) -> [TeacherPose]``: the careful pipeline on one frame.

    Args:
        models: {name: ObjectModel} of the objects to label.
        base: the PipelineOptions the careful settings are laid over (``teacher_options``).
        weights: the networks' weight files (the ones being adapted).
        score_threshold: lowest detector score the teacher looks at (0..1).

    """

    def __init__(self, models: Mapping[str, ObjectModel], base: PipelineOptions,
                 weights: WeightFiles, score_threshold: float) -> None:
        self.models = dict(models)
        self.options = teacher_options(base, score_threshold)
        self.pipeline = load_pipeline(self.models, self.options, weights)

    def __call__(self, image_rgb: np.ndarray, camera: CameraIntrinsics) -> list[TeacherPose]:
        """Find, refine and keep every pose of the frame; highest detection score first."""
        poses = []
        for pose in self.pipeline.estimate(image_rgb, camera).poses:
            try:
                box = projected_box_uv(camera, self.models[pose.object_name].hull_points,
                                       pose.rotation, pose.translation)
            except InputError:      # part of the mesh behind the camera: no label
                continue
            poses.append(TeacherPose(pose.object_name, float(pose.detection.score),
                                     np.asarray(pose.detection.box_uv, dtype=float),
                                     np.asarray(pose.rotation, dtype=float),
                                     np.asarray(pose.translation, dtype=float),
                                     float(pose.confidence), box))
        return sorted(poses, key=lambda p: -p.detection_score)
