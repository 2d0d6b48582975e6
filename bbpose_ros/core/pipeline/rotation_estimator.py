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
The rotation stage: (image, camera, detections) -> egocentric rotations from Q-Net.

``QNetRotationEstimator`` returns (N, 3, 3) model-to-camera rotations, or all of a
multi-hypothesis Q-Net's rotations (``poses.RotationHypotheses``) for the pipeline to rank;
an allocentric Q-Net's output is turned egocentric with the ray through each box centre.
"""

from __future__ import annotations

from collections.abc import Sequence
import copy

import numpy as np
from scipy.special import log_softmax
import torch
from torch import nn

from bbpose_ros.core.geometry.boxes import box_centres
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.rotations import quat_multiply, quat_wxyz_to_matrix, ray_quaternion
from bbpose_ros.core.inference.backends import graph_runner, make_runner
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.nets.crops import extract_crops, FILL_VALUE, square_boxes
from bbpose_ros.core.nets.qnet import HypothesisOutputs, QNet
from bbpose_ros.core.pipeline.poses import Detection, RotationHypotheses
from bbpose_ros.core.util.errors import InputError


class QNetRotationEstimator:
    """
    Rotation estimator callable: ``(image_rgb, camera, detections) -> (N, 3, 3)``.

    All crops of a frame go through Q-Net in one batch. Output rotations are egocentric
    (model-to-camera, x_cam = R x_model + t) whatever the network's target.

    Args:
        network: a QNet (a copy is prepared for inference by ``make_runner``); a per_object
            one (its forward branches on the object indices) needs the torch backend.
        options: the PipelineOptions: what runs the network (``backends.make_runner``).
        all_hypotheses: return every hypothesis of a multi-hypothesis network as
            RotationHypotheses (N, H) instead of its best-scored rotations (N, 3, 3).
        int8_graph: the network's int8 graph (``int8_graphs.choose_int8_graph``, checked
            against its weight file), run by ONNX Runtime in place of the float network;
            None: the float network.

    Attributes:
        precision: 'int8' or 'fp32', what runs the network.

    """

    def __init__(self, network: QNet, options: PipelineOptions, all_hypotheses: bool = False,
                 int8_graph=None) -> None:
        self.config = network.config
        if self.config.sharing == 'per_object' and options.inference_backend != 'torch':
            raise InputError(f'a per_object Q-Net runs only on the torch backend, not on '
                             f'{options.inference_backend}')
        self.index = {name: k for k, name in enumerate(self.config.objects)}
        self.all_hypotheses = all_hypotheses
        self.precision = 'fp32' if int8_graph is None else 'int8'
        # The int8 graph holds every hypothesis; the best is picked here when only it is
        # wanted.
        self._pick_best = int8_graph is not None and not all_hypotheses
        if int8_graph is None:
            self.network = make_runner(run_network(network, all_hypotheses),
                                       self._blank_batch(1), options, dynamic_batch=True)
        else:
            self.network = graph_runner(int8_graph.SerializeToString(), options)

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
        if self._pick_best:
            quaternions, logits = outputs
            outputs = quaternions[torch.arange(len(quaternions)), logits.argmax(dim=1)]
        q_wxyz = (outputs[0] if self.all_hypotheses else outputs).cpu().numpy().reshape(-1, 4)
        if self.config.rotation_target == 'allocentric':
            # R_ego = V R_allo, composed as quaternions: fewer array operations than matrices.
            rays = camera.rays(box_centres(boxes))
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


def run_network(network: QNet, all_hypotheses: bool = True) -> nn.Module:
    """
    Return the copy of ``network`` an estimator runs (and an int8 graph holds, with all).

    It leaves out the q-normalization layer: quaternions are only turned into matrices here,
    and ``quat_wxyz_to_matrix`` takes any length (three kernels fewer). With
    ``all_hypotheses`` its outputs are every hypothesis (``HypothesisOutputs``: (N, H, 4)
    quaternions and (N, H) logits), else the best-scored (N, 4) quaternions.
    """
    network = copy.deepcopy(network)
    network.normalize = nn.Identity()
    return HypothesisOutputs(network) if all_hypotheses else network
