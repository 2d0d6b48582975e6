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
The learned stages as pipeline callables, and ``load_pipeline`` that wires them up.

* ``BoxDetector``: image -> list[Detection] (amodal boxes, continuous pixels) with the
  CenterNet-style detector of ``nets.detector``.
* ``QNetRotationEstimator``: (image, camera, detections) -> (N, 3, 3) egocentric
  model-to-camera rotations from Q-Net, or all of a multi-hypothesis Q-Net's rotations
  (``hypotheses.RotationHypotheses``) for the pipeline to choose from; an allocentric
  Q-Net's output is turned egocentric with the ray through each box centre.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping, Sequence
import copy
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
from scipy.special import log_softmax
import torch
from torch import nn

from bbpose_ros.core.errors import InputError
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.rotations import quat_multiply, quat_wxyz_to_matrix, ray_quaternion
from bbpose_ros.core.nets.crops import box_centre_rays, extract_crops, FILL_VALUE
from bbpose_ros.core.nets.crops import square_boxes
from bbpose_ros.core.nets.detector import CenterBoxNet, peak_boxes, PeakOutputs
from bbpose_ros.core.nets.qnet import HypothesisOutputs, QNet
from bbpose_ros.core.pipeline.backends import make_runner
from bbpose_ros.core.pipeline.hypotheses import (DEFAULT_BOX_CONSISTENCY_WEIGHT,
                                                 HypothesisSelector, RotationHypotheses)
from bbpose_ros.core.pipeline.pose_pipeline import Detection, PosePipeline
from bbpose_ros.core.pipeline.refinement import load_pose_refiner
from bbpose_ros.core.pipeline.weights import (DEFAULT_DETECTOR_WEIGHTS, DEFAULT_QNET_WEIGHTS,
                                              load_network)

if TYPE_CHECKING:
    from bbpose_ros.core.data.models import ObjectModel

# Largest Q-Net batch run at load time (see QNetRotationEstimator.warm_up).
MAX_WARM_UP_BATCH = 16


class BoxDetector:
    """
    Detector callable: ``detect(image_rgb (H, W, 3) uint8) -> list[Detection]``.

    With a second stage (``network.verifier``), the ``candidates`` highest heatmap peaks of
    each wanted class are re-scored on crops of the network input: the score of a detection
    is the second stage's probability of its class, its box the second stage's correction.

    Args:
        network: a CenterBoxNet (a copy is prepared for inference by ``make_runner``).
        names: object names to report (a subset of the network's classes).
        score_threshold: lowest detection score reported.
        max_instances: most detections per object name.
        backend, device, threads: see ``backends.make_runner``.

    """

    def __init__(self, network: CenterBoxNet, names: Collection[str],
                 score_threshold: float = 0.3, max_instances: int = 1,
                 backend: str = 'onnxruntime', device: str | torch.device = 'cpu',
                 threads: int | None = None) -> None:
        self.config = network.config
        in_w, in_h = self.config.input_size
        self.blank = np.zeros((1, in_h, in_w, 3), np.uint8)
        self.grid_width = in_w // self.config.stride
        self.verifier = None
        if network.verifier is not None:
            self.verifier = make_runner(network.verifier, self._blank_crops(1), backend,
                                        device, threads, dynamic_batch=True)
        count = self.config.candidates if network.verifier is not None else max_instances
        count = min(count, self.grid_width * (in_h // self.config.stride))
        # The peak search runs inside the graph: cheaper than torch calls on its outputs.
        self.network = make_runner(PeakOutputs(network, count), (self.blank,), backend, device,
                                   threads)
        self.wanted = np.array([name in set(names) for name in self.config.objects])
        self.score_threshold = score_threshold
        self.max_instances = max_instances

    def __call__(self, image_rgb: np.ndarray) -> list[Detection]:
        """Detect the wanted objects; highest score first."""
        height, width = image_rgb.shape[:2]
        in_w, in_h = self.config.input_size
        small = cv2.resize(image_rgb, (in_w, in_h), interpolation=cv2.INTER_AREA)
        outputs = [x[0].cpu().numpy() for x in self.network(small[None])]
        if self.verifier is None:
            classes, scores, boxes = peak_boxes(*outputs, self.grid_width, self.config.stride,
                                                self.score_threshold)
        else:
            classes, scores, boxes = self._second_stage(small, outputs)
        scale = np.array([width / in_w, height / in_h] * 2)
        boxes = (boxes.astype(float) + 0.5) * scale - 0.5
        return [Detection(self.config.objects[c], float(s), b)
                for c, s, b in zip(classes.tolist(), scores.tolist(), boxes)
                if self.wanted[c]]

    def _second_stage(self, small, outputs):
        """Candidates of the wanted classes re-scored and re-boxed by the verifier."""
        classes, _, boxes = peak_boxes(*outputs, self.grid_width, self.config.stride,
                                       self.config.candidate_threshold)
        keep = self.wanted[classes]
        classes, boxes = classes[keep], boxes[keep]
        if not len(classes):
            return classes, np.zeros(0, np.float32), boxes
        squares = square_boxes(boxes, self.config.verifier_context)
        crops = extract_crops(small, squares, self.config.verifier_crop_size)
        scores, corrections = self.verifier(crops, classes.astype(np.int64))
        boxes = boxes + corrections.cpu().numpy() * (squares[:, 2:3] - squares[:, 0:1])
        boxes[:, 2:] = np.maximum(boxes[:, 2:], boxes[:, :2] + 1.0)   # never inside out
        return best_per_class(classes, scores.cpu().numpy(), boxes, self.score_threshold,
                              self.max_instances)

    def _blank_crops(self, count):
        size = self.config.verifier_crop_size
        return (np.full((count, size, size, 3), FILL_VALUE, dtype=np.uint8),
                np.zeros(count, dtype=np.int64))

    def warm_up(self) -> None:
        """Run the networks once on blank inputs, the verifier at every batch size."""
        self.network(self.blank)
        if self.verifier is not None:
            for count in range(1, self.config.candidates * int(self.wanted.sum()) + 1):
                self.verifier(*self._blank_crops(count))


def best_per_class(classes: np.ndarray, scores: np.ndarray, boxes: np.ndarray,
                   score_threshold: float,
                   max_per_class: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Keep the ``max_per_class`` best detections of each class scored >= ``score_threshold``.

    Args:
        classes: (K,) class indices.
        scores: (K,) scores.
        boxes: (K, 4) boxes.

    Returns:
        (classes, scores, boxes) of the kept detections, highest score first.

    """
    order = np.argsort(-scores, kind='stable')
    order = order[scores[order] >= score_threshold]
    taken = {}
    kept = []
    for k in order.tolist():
        count = taken.get(classes[k], 0)
        if count < max_per_class:
            taken[classes[k]] = count + 1
            kept.append(k)
    return classes[kept], scores[kept], boxes[kept]


class QNetRotationEstimator:
    """
    Rotation estimator callable: ``(image_rgb, camera, detections) -> (N, 3, 3)``.

    All crops of a frame go through Q-Net in one batch. Output rotations are egocentric
    (model-to-camera, x_cam = R x_model + t) whatever the network's target.

    Args:
        network: a QNet (a copy is prepared for inference by ``make_runner``); a per_object
            one (its forward branches on the object indices) needs the torch backend.
        backend, device, threads: see ``backends.make_runner``.
        all_hypotheses: return every hypothesis of a multi-hypothesis network as
            RotationHypotheses (N, H) instead of its best-scored rotations (N, 3, 3).

    """

    def __init__(self, network: QNet, backend: str = 'onnxruntime',
                 device: str | torch.device = 'cpu', threads: int | None = None,
                 all_hypotheses: bool = False) -> None:
        self.config = network.config
        if self.config.sharing == 'per_object' and backend != 'torch':
            raise InputError(f'a per_object Q-Net runs only on the torch backend, not on '
                             f'{backend}')
        self.index = {name: k for k, name in enumerate(self.config.objects)}
        # The run leaves out the q-normalization layer: quaternions are only turned into
        # matrices here, and quat_wxyz_to_matrix takes any length (three kernels fewer).
        network = copy.deepcopy(network)
        network.normalize = nn.Identity()
        self.all_hypotheses = all_hypotheses
        if all_hypotheses:
            network = HypothesisOutputs(network)
        self.network = make_runner(network, self._blank_batch(1), backend, device, threads,
                                   dynamic_batch=True)

    def __call__(self, image_rgb: np.ndarray, camera: CameraIntrinsics,
                 detections: Sequence[Detection]) -> np.ndarray | RotationHypotheses:
        """Egocentric rotations (N, 3, 3), one per detection, or RotationHypotheses."""
        count = self.config.hypotheses if self.all_hypotheses else 1
        if not detections:
            if self.all_hypotheses:
                return RotationHypotheses(np.zeros((0, count, 3, 3)), np.zeros((0, count)))
            return np.zeros((0, 3, 3))
        boxes = np.array([d.box_uv for d in detections], dtype=float)
        crops = extract_crops(image_rgb, square_boxes(boxes, self.config.context),
                              self.config.crop_size)
        index = np.array([self.index[d.object_name] for d in detections], dtype=np.int64)
        outputs = self.network(crops, index)
        q_wxyz = (outputs[0] if self.all_hypotheses else outputs).cpu().numpy().reshape(-1, 4)
        if self.config.rotation_target == 'allocentric':
            # R_ego = V R_allo, composed as quaternions: fewer array operations than matrices.
            rays = box_centre_rays(boxes, camera)
            q_wxyz = quat_multiply(ray_quaternion(np.repeat(rays, count, axis=0)), q_wxyz)
        rotations = quat_wxyz_to_matrix(q_wxyz)
        if not self.all_hypotheses:
            return rotations
        return RotationHypotheses(rotations.reshape(-1, count, 3, 3),
                                  log_softmax(outputs[1].cpu().numpy().astype(float), axis=1))

    def _blank_batch(self, count):
        size = self.config.crop_size
        crops = np.full((count, size, size, 3), FILL_VALUE, dtype=np.uint8)
        return crops, np.zeros(count, dtype=np.int64)

    def warm_up(self, max_batch: int) -> None:
        """
        Run every batch size 1..max_batch once, on blank crops.

        Both backends prepare kernels and memory on the first call with each input shape
        (torch's oneDNN prepares its kernels for each new batch size). Done here, that
        stays out of the first frames.
        """
        for count in range(1, max_batch + 1):
            self.network(*self._blank_batch(count))


def load_pipeline(models: Mapping[str, ObjectModel], detector_weights: Path | str | None = None,
                  qnet_weights: Path | str | None = None, score_threshold: float = 0.3,
                  max_instances: int = 1, backend: str = 'onnxruntime',
                  device: str | torch.device = 'cpu', threads: int | None = None,
                  box_consistency_weight: float = DEFAULT_BOX_CONSISTENCY_WEIGHT,
                  refine: bool = False, refine_hypotheses: int = 1,
                  refine_min_score: float = 0.0,
                  refiner_log: Callable[[str], None] | None = None) -> PosePipeline:
    """
    Build a PosePipeline with the learned detector and Q-Net.

    Args:
        models: {name: ObjectModel}; every name must be covered by both weight files.
        detector_weights: detector file (default: the shipped ``weights/detector.pt``).
        qnet_weights: Q-Net file (default: the shipped ``weights/qnet.pt``).
        score_threshold: lowest detector score reported (0..1).
        max_instances: most detections per object and frame.
        backend: inference backend, 'onnxruntime' or 'torch' (see ``backends``).
        device: torch device, e.g. 'cpu' ('onnxruntime' runs on the CPU only).
        threads: intra-op threads of torch and ONNX Runtime (None: their defaults).
        box_consistency_weight: with a multi-hypothesis Q-Net, how much the Bounding Box
            Equation's misfit counts in choosing a hypothesis (``hypotheses``); 0: the
            network's best-scored one.
        refine: add the region-based refinement stage (``refinement.load_pose_refiner``:
            viewpoint models from the cache, built on first use).
        refine_hypotheses: with refinement, how many of each detection's best-ranked
            rotation hypotheses are refined (the best-scored one is kept).
        refine_min_score: with refinement, drop poses scored below this (0..1).
        refiner_log: gets a line for each viewpoint model built.

    Returns:
        PosePipeline(models, detector, rotation_estimator, hypothesis_selector, refiner).

    Raises:
        InputError: a missing, corrupt or mismatched weight file, or a bad argument.

    """
    if not 0.0 <= score_threshold <= 1.0:
        raise InputError(f'score_threshold must be in [0, 1], got {score_threshold}')
    if max_instances < 1:
        raise InputError(f'max_instances must be at least 1, got {max_instances}')
    selector = HypothesisSelector(models, box_consistency_weight)
    if threads is not None:
        if threads < 1:
            raise InputError(f'threads must be at least 1, got {threads}')
        torch.set_num_threads(int(threads))
    names = list(models)
    detector = BoxDetector(
        load_network(detector_weights or DEFAULT_DETECTOR_WEIGHTS, 'detector', names), names,
        score_threshold, max_instances, backend, device, threads)
    qnet = load_network(qnet_weights or DEFAULT_QNET_WEIGHTS, 'qnet', names)
    rotation = QNetRotationEstimator(
        qnet, backend, device, threads,
        all_hypotheses=qnet.config.hypotheses > 1 and (
            selector.weight > 0 or (refine and refine_hypotheses > 1)))
    detector.warm_up()
    rotation.warm_up(min(len(names) * max_instances, MAX_WARM_UP_BATCH))
    refiner = None
    if refine:
        refiner = load_pose_refiner(models, min_score=refine_min_score, progress=False,
                                    log=refiner_log)
    return PosePipeline(models, detector, rotation, hypothesis_selector=selector,
                        refiner=refiner, refine_hypotheses=refine_hypotheses)
