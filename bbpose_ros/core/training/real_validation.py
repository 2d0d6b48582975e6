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
``RealDetections``: the detector's recall and AP, as ``bbpose eval`` scores them.
``RealDenseCrops``: the dense net's masks and PnP poses with ground-truth boxes. These
frames only measure: nothing here feeds the optimiser.
"""

from __future__ import annotations

from collections.abc import Collection, Iterable, Mapping
from typing import Any, TYPE_CHECKING

import numpy as np

from bbpose_ros.core.eval.detection import score_detections
from bbpose_ros.core.eval.instance_scores import score_instance, summarize_objects
from bbpose_ros.core.geometry.dense_grid import model_box
from bbpose_ros.core.geometry.dense_pnp import pose_from_dense_maps
from bbpose_ros.core.inference.backends import TorchRunner
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.nets.crops import extract_crops, square_boxes
from bbpose_ros.core.nets.dense import DenseConfig, DenseNet
from bbpose_ros.core.nets.detector import CenterBoxNet
from bbpose_ros.core.nets.qnet import QNet
from bbpose_ros.core.pipeline.box_detector import BoxDetector
from bbpose_ros.core.pipeline.poses import Detection, PoseEstimate
from bbpose_ros.core.pipeline.rotation_estimator import QNetRotationEstimator
from bbpose_ros.core.render import Draw, Lighting, MeshRenderer, RenderMesh
from bbpose_ros.core.training.dense_training import maps_to_numpy, mask_iou
from bbpose_ros.core.util.errors import InputError

if TYPE_CHECKING:
    from bbpose_ros.core.data.bop import BopFrame
    from bbpose_ros.core.data.models import ObjectModel

# The validations run the networks as trained: eager torch, on the pipeline's default device.
EAGER = PipelineOptions(inference_backend='torch')


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
        estimate = QNetRotationEstimator(network, EAGER)
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
    Real frames for the detector, scored with the shipped score threshold and instances.

    The threshold and the instances per name are ``PipelineOptions``' defaults.

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
        detector = BoxDetector(network, self.objects, EAGER)
        report = score_detections(self.frames, [detector(image) for image in self.images],
                                  self.objects)
        return {'real_recall50_visib30': report['mean']['recall_iou50_visib30'],
                'real_ap50': report['mean']['ap50']}


class RealDenseCrops:
    """
    The ground-truth instances of some real frames for a dense net: crops and true masks.

    Crops are cut around the ground-truth amodal boxes as Q-Net's are (square, the net's
    ``context``). The true masks are rendered from the ground truth through each crop's
    camera: the visible mask (the frame's annotated objects occluding each other; other
    clutter is not modelled) and the amodal mask, as cell shares of the net's grid. The
    poses come from ``pose_from_dense_maps`` and are scored as ``bbpose eval`` scores them.

    Args:
        frames: BopFrame sequence.
        config: the net's DenseConfig.
        models: {name: ObjectModel} of all annotated objects (occluders too).
        min_visib: smallest visible fraction kept (0.1 as in ``bbpose eval``).

    """

    def __init__(self, frames: Iterable[BopFrame], config: DenseConfig,
                 models: Mapping[str, ObjectModel], min_visib: float = 0.1) -> None:
        self.config, self.models = config, models
        self.boxes = {name: model_box(models[name].vertices) for name in config.objects}
        size = config.map_size
        renderer = None
        crops, self.instances, visible, amodal = [], [], [], []
        for frame in frames:
            targets = [i for i in frame.instances
                       if i.object_name in config.objects and i.visib_fract >= min_visib]
            if not targets:
                continue
            if renderer is None:
                renderer = MeshRenderer(frame.camera.cropped((0, 0, 1, 1), 2 * size),
                                        {name: RenderMesh.from_object_model(model)
                                         for name, model in models.items()})
            draws = [Draw(i.object_name, i.rotation, i.translation) for i in frame.instances
                     if i.object_name in models]
            image = frame.load_image()
            squares = square_boxes(np.array([i.box_uv for i in targets]), config.context)
            crops.append(extract_crops(image, squares, config.crop_size))
            for instance, square in zip(targets, squares):
                index = [d.mesh for d in draws].index(instance.object_name)
                rendered = renderer.render(draws, Lighting(), (index,),
                                           frame.camera.cropped(square, 2 * size))
                visible.append(_cell_shares(rendered.instance_ids == index + 1, size))
                amodal.append(_cell_shares(rendered.full_masks[index], size))
                self.instances.append((frame, instance, square))
        if renderer is not None:
            renderer.close()
        if not self.instances:
            raise InputError("no real instance of the dense net's objects to validate on")
        self.crops = np.concatenate(crops)
        self.visible, self.amodal = np.array(visible), np.array(amodal)
        self.object_index = np.array([config.objects.index(i.object_name)
                                      for _, i, _ in self.instances])

    def __len__(self) -> int:
        return len(self.instances)

    def predict(self, network: DenseNet, batch: int = 64) -> tuple[np.ndarray, ...]:
        """Return the maps of every crop: coordinates (n, M, M, 3), visible, amodal (n, M, M)."""
        runner = TorchRunner(network, EAGER.device)
        parts = [maps_to_numpy(runner(self.crops[k:k + batch],
                                      self.object_index[k:k + batch]))
                 for k in range(0, len(self.crops), batch)]
        return tuple(np.concatenate(p) for p in zip(*parts))

    def report(self, network: DenseNet) -> dict[str, Any]:
        """
        Score the net's PnP poses and masks.

        ``bbpose eval``'s {'objects', 'mean'} figures of the PnP poses (ground-truth boxes,
        unrefined; an instance PnP cannot solve counts as missed), plus per object and on
        average the mean visible and amodal mask IoU ('visible_iou', 'amodal_iou').
        """
        coordinates, visible_p, amodal_p = self.predict(network)
        visible_iou = mask_iou(visible_p, self.visible)
        amodal_iou = mask_iou(amodal_p, self.amodal)
        scores = {name: [] for name in self.config.objects}
        ious = {name: ([], []) for name in self.config.objects}
        for k, (frame, instance, square) in enumerate(self.instances):
            name = instance.object_name
            found = pose_from_dense_maps(coordinates[k], visible_p[k], square, frame.camera,
                                         *self.boxes[name])
            pose = None if found is None else PoseEstimate(
                Detection(name, 1.0, instance.box_uv), found.rotation, found.translation)
            scores[name].append(score_instance(self.models[name], instance, pose,
                                               frame.camera))
            ious[name][0].append(visible_iou[k])
            ious[name][1].append(amodal_iou[k])
        report = summarize_objects({n: s for n, s in scores.items() if s})
        for name, row in report['objects'].items():
            row['visible_iou'] = float(np.mean(ious[name][0]))
            row['amodal_iou'] = float(np.mean(ious[name][1]))
        for key in ('visible_iou', 'amodal_iou'):
            report['mean'][key] = float(np.mean([r[key] for r in report['objects'].values()]))
        return report

    def figures(self, network: DenseNet) -> dict[str, float]:
        """Return the log's real-frame figures: means over objects of ``report``."""
        mean = self.report(network)['mean']
        return {'real_re_median_deg': mean['re_median_deg'],
                'real_te_median_mm': mean['te_median_mm'],
                'real_add_s': mean['add_s_recall'], 'real_cm5deg5': mean['cm5deg5'],
                'real_visible_iou': mean['visible_iou'],
                'real_amodal_iou': mean['amodal_iou']}


def _cell_shares(mask, size):
    """(size, size) share of each grid cell a (R, R) bool mask covers."""
    cell = mask.shape[0] // size
    return mask.reshape(size, cell, size, cell).mean(axis=(1, 3))
