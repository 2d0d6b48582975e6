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
The detection stage: image -> list[Detection] (amodal boxes, continuous pixels).

``BoxDetector`` runs the CenterNet-style detector of ``nets.detector`` (its peak search
inside the exported graph) and, when the network has one, its second stage.
"""

from __future__ import annotations

from collections.abc import Collection

import cv2
import numpy as np

from bbpose_ros.core.inference.backends import graph_runner, make_runner
from bbpose_ros.core.inference.int8_graphs import with_peak_search
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.nets.crops import extract_crops, FILL_VALUE, square_boxes
from bbpose_ros.core.nets.detector import CenterBoxNet, peak_boxes, PeakOutputs
from bbpose_ros.core.pipeline.poses import Detection


class BoxDetector:
    """
    Detector callable: ``detect(image_rgb (H, W, 3) uint8) -> list[Detection]``.

    With a second stage (``network.verifier``), the ``candidates`` highest heatmap peaks of
    each wanted class are re-scored on crops of the network input: the score of a detection
    is the second stage's probability of its class, its box the second stage's correction.

    Args:
        network: a CenterBoxNet (a copy is prepared for inference by ``make_runner``).
        names: object names to report (a subset of the network's classes).
        options: the PipelineOptions: ``score_threshold`` and ``max_instances`` here, what
            runs the networks in ``backends.make_runner``.
        int8_graph: the network's int8 graph (``int8_graphs.choose_int8_graph``, checked
            against the network's weight file), run by ONNX Runtime in place of the float
            network; None: the float network. The second stage stays float.

    Attributes:
        precision: 'int8' or 'fp32', what runs the heatmap network.

    """

    def __init__(self, network: CenterBoxNet, names: Collection[str], options: PipelineOptions,
                 int8_graph=None) -> None:
        self.config = network.config
        self.options = options
        in_w, in_h = self.config.input_size
        self.blank = np.zeros((1, in_h, in_w, 3), np.uint8)
        self.grid_width = in_w // self.config.stride
        self.verifier = None
        if network.verifier is not None:
            self.verifier = make_runner(network.verifier, self._blank_crops(1), options,
                                        dynamic_batch=True)
        count = self.config.candidates if network.verifier is not None else \
            options.max_instances
        count = min(count, self.grid_width * (in_h // self.config.stride))
        # The peak search runs inside the graph: cheaper than torch calls on its outputs.
        if int8_graph is None:
            self.network = make_runner(PeakOutputs(network, count), (self.blank,), options)
        else:
            self.network = graph_runner(with_peak_search(int8_graph, self.config, count),
                                        options)
        self.precision = 'fp32' if int8_graph is None else 'int8'
        self.wanted = np.array([name in set(names) for name in self.config.objects])

    def __call__(self, image_rgb: np.ndarray) -> list[Detection]:
        """Detect the wanted objects; highest score first."""
        height, width = image_rgb.shape[:2]
        in_w, in_h = self.config.input_size
        small = cv2.resize(image_rgb, (in_w, in_h), interpolation=cv2.INTER_AREA)
        outputs = [x[0].cpu().numpy() for x in self.network(small[None])]
        if self.verifier is None:
            classes, scores, boxes = peak_boxes(*outputs, self.grid_width, self.config.stride,
                                                self.options.score_threshold)
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
        return best_per_class(classes, scores.cpu().numpy(), boxes,
                              self.options.score_threshold, self.options.max_instances)

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
