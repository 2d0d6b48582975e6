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
The learned stages on real frames: the sim-to-real figures, watched while training.

``RealCrops``: Q-Net with ground-truth boxes; the crops are cut exactly as
``QNetRotationEstimator`` cuts them; the error is the rotation error (degrees) to the closest
symmetric equivalent of the ground truth, as in ``metrics.cm_deg_errors``.
``RealDetections``: the detector's recall and AP, as ``bbpose eval`` scores them. These
frames only measure: nothing here feeds the optimiser.
"""

from __future__ import annotations

from collections.abc import Collection, Iterable, Mapping
from typing import TYPE_CHECKING

import numpy as np

from bbpose_ros.core.eval.detection import score_detections
from bbpose_ros.core.nets.detector import CenterBoxNet
from bbpose_ros.core.nets.qnet import QNet
from bbpose_ros.core.pipeline.box_detector import BoxDetector
from bbpose_ros.core.pipeline.poses import Detection
from bbpose_ros.core.pipeline.rotation_estimator import QNetRotationEstimator

if TYPE_CHECKING:
    from bbpose_ros.core.data.bop import BopFrame
    from bbpose_ros.core.data.models import ObjectModel


class RealCrops:
    """
    The ground-truth instances of some real frames, for one Q-Net configuration.

    Args:
        frames: BopFrame sequence.
        objects: names the network knows; other instances are skipped.
        models: {name: ObjectModel}, for the symmetry transforms.
        min_visib: smallest visible fraction kept (0.1 as in ``bbpose eval``).

    """

    def __init__(self, frames: Iterable[BopFrame], objects: Collection[str],
                 models: Mapping[str, ObjectModel], min_visib: float = 0.1) -> None:
        self.items = []
        for frame in frames:
            instances = [i for i in frame.instances
                         if i.object_name in objects and i.visib_fract >= min_visib]
            if instances:
                self.items.append((frame, frame.load_image(), instances))
        self.symmetries = {name: models[name].symmetry_transforms[:, :3, :3]
                           for name in objects}

    def __len__(self) -> int:
        return sum(len(instances) for _, _, instances in self.items)

    def rotation_errors(self, network: QNet) -> np.ndarray:
        """(n,) degrees: symmetry-aware rotation error of every instance, GT boxes."""
        estimate = QNetRotationEstimator(network, backend='torch')
        errors = []
        for frame, image, instances in self.items:      # the runner is in inference mode
            detections = [Detection(i.object_name, 1.0, i.box_uv) for i in instances]
            rotations = estimate(image, frame.camera, detections)
            for rotation, instance in zip(rotations, instances):
                candidates = instance.rotation @ self.symmetries[instance.object_name]
                cos = (np.einsum('ij,kij->k', rotation, candidates) - 1) / 2
                errors.append(np.degrees(np.arccos(np.clip(cos, -1, 1))).min())
        return np.array(errors)

    def figures(self, network: QNet) -> dict[str, float]:
        """Median rotation error (deg) and the shares under 15 and 30 deg, for the log."""
        errors = self.rotation_errors(network)
        return {'real_median_deg': float(np.median(errors)),
                'real_acc15': float(np.mean(errors < 15)),
                'real_acc30': float(np.mean(errors < 30))}


class RealDetections:
    """
    Real frames for the detector, scored as by ``load_pipeline`` (score 0.3, one a name; torch).

    Args:
        frames: BopFrame sequence.
        objects: the names to detect and score.

    """

    def __init__(self, frames: Iterable[BopFrame], objects: Iterable[str]) -> None:
        self.frames = list(frames)
        self.images = [frame.load_image() for frame in self.frames]
        self.objects = list(objects)

    def figures(self, network: CenterBoxNet) -> dict[str, float]:
        """Mean recall at IoU 0.5 (visible fraction >= 0.3) and AP50 of a CenterBoxNet."""
        detector = BoxDetector(network, self.objects, backend='torch')
        report = score_detections(self.frames, [detector(image) for image in self.images],
                                  self.objects)
        return {'real_recall50_visib30': report['mean']['recall_iou50_visib30'],
                'real_ap50': report['mean']['ap50']}
