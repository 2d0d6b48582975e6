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

"""Inference backends: folded networks and ONNX Runtime compute what the trained net does."""

import numpy as np
import pytest
import torch

from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.inference.backends import inference_network, make_runner
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.nets.detector import CenterBoxNet, DetectorConfig
from bbpose_ros.core.nets.images import images_to_input
from bbpose_ros.core.nets.qnet import QNet, QNetConfig
from bbpose_ros.core.pipeline.box_detector import BoxDetector
from bbpose_ros.core.pipeline.poses import Detection
from bbpose_ros.core.pipeline.rotation_estimator import QNetRotationEstimator
from bbpose_ros.core.util.errors import InputError

OBJECTS = ('ape', 'can', 'cat', 'driller', 'duck', 'eggbox', 'glue', 'holepuncher')
RNG = np.random.default_rng(5)
TORCH = PipelineOptions(inference_backend='torch')
ONNX_1 = PipelineOptions(inference_threads=1)


def _images(count, height, width):
    """(count, height, width, 3) random uint8 RGB images."""
    return RNG.integers(0, 256, (count, height, width, 3), dtype=np.uint8)


def _trained_looking(network):
    """Give every BatchNorm non-trivial statistics, so that folding them is tested."""
    torch.manual_seed(3)
    for norm in [m for m in network.modules() if isinstance(m, torch.nn.BatchNorm2d)]:
        norm.running_mean.uniform_(-0.5, 0.5)
        norm.running_var.uniform_(0.5, 2.0)
        norm.weight.data.uniform_(0.5, 1.5)
        norm.bias.data.uniform_(-0.2, 0.2)
    return network.eval()


def test_folded_copy_computes_the_same_function():
    net = _trained_looking(QNet(QNetConfig(OBJECTS)))
    folded = inference_network(net, 'cpu')
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in folded.modules())
    assert any(isinstance(m, torch.nn.BatchNorm2d) for m in net.modules())   # untouched
    crops, index = torch.rand(6, 3, 48, 48), torch.tensor([0, 1, 5, 6, 7, 0])
    with torch.inference_mode():
        torch.testing.assert_close(folded(crops, index), net(crops, index), atol=1e-5, rtol=0)


@pytest.mark.parametrize('batch', [1, 3, 8])
@pytest.mark.parametrize('first_stride, hypotheses, backbone', [
    (1, 1, 'scratch'), (2, 1, 'scratch'), (2, 8, 'scratch'), (1, 8, 'lite0')])
def test_onnxruntime_qnet_matches_torch_for_any_batch(batch, first_stride, hypotheses,
                                                      backbone):
    size = 64 if backbone == 'lite0' else 48
    net = _trained_looking(QNet(QNetConfig(OBJECTS, crop_size=size, first_stride=first_stride,
                                           hypotheses=hypotheses, backbone=backbone)))
    example = (_images(2, size, size), np.array([0, 1]))     # traced with batch 2
    onnx = make_runner(net, example, ONNX_1, dynamic_batch=True)
    crops, index = _images(batch, size, size), RNG.integers(0, len(OBJECTS), batch)
    with torch.inference_mode():
        expected = net(images_to_input(torch.from_numpy(crops)), torch.from_numpy(index))
    torch.testing.assert_close(onnx(crops, index), expected, atol=1e-5, rtol=0)
    torch.testing.assert_close(make_runner(net, example, TORCH)(crops, index), expected,
                               atol=1e-5, rtol=0)


@pytest.mark.parametrize('backbone', ['scratch', 'lite0'])
def test_onnxruntime_detector_matches_torch(backbone):
    net = _trained_looking(CenterBoxNet(DetectorConfig(OBJECTS, backbone=backbone)))
    width, height = net.config.input_size
    image = _images(1, height, width)
    with torch.inference_mode():
        expected = net(images_to_input(torch.from_numpy(image)))
    outputs = make_runner(net, (image,), ONNX_1)(image)
    assert len(outputs) == len(expected) == 2
    for got, want in zip(outputs, expected):
        torch.testing.assert_close(got, want, atol=1e-4, rtol=1e-4)


def test_second_stage_detections_agree_between_backends():
    net = _trained_looking(CenterBoxNet(DetectorConfig(OBJECTS,
                                                       verifier_channels=(8, 8, 16, 16))))
    image = _images(1, 480, 640)[0]
    found = [BoxDetector(net, OBJECTS, PipelineOptions(score_threshold=0.0, max_instances=2,
                                                       inference_backend=backend,
                                                       inference_threads=1))(image)
             for backend in ('torch', 'onnxruntime')]
    assert len(found[0]) == len(found[1]) == 2 * len(OBJECTS)
    for a, b in zip(*found):
        assert a.object_name == b.object_name
        assert abs(a.score - b.score) < 1e-5
        np.testing.assert_allclose(a.box_uv, b.box_uv, atol=1e-3)


@pytest.mark.parametrize('target, count', [('egocentric', 8), ('allocentric', 8),
                                           ('allocentric', 1)])
def test_all_hypotheses_agree_between_backends_and_hold_the_best_scored(target, count):
    net = _trained_looking(QNet(QNetConfig(OBJECTS, hypotheses=count, rotation_target=target)))
    camera = CameraIntrinsics(572.4, 573.6, 325.3, 242.0, 640, 480)
    image = _images(1, 480, 640)[0]
    detections = [Detection(name, 1.0, np.array([40.0 + 60 * k, 30.0, 130.0 + 60 * k, 150.0]))
                  for k, name in enumerate(OBJECTS[:5])]
    found = [QNetRotationEstimator(net, options, all_hypotheses=True)(image, camera, detections)
             for options in (TORCH, ONNX_1)]
    for hypotheses in found:
        assert hypotheses.rotations.shape == (5, count, 3, 3)
        assert hypotheses.log_probs.shape == (5, count)
    np.testing.assert_allclose(found[0].rotations, found[1].rotations, atol=1e-5)
    np.testing.assert_allclose(found[0].log_probs, found[1].log_probs, atol=1e-4)
    np.testing.assert_allclose(np.exp(found[0].log_probs).sum(axis=1), 1.0, atol=1e-6)
    best = found[0].rotations[np.arange(5), found[0].log_probs.argmax(axis=1)]
    np.testing.assert_allclose(QNetRotationEstimator(net, TORCH)(image, camera, detections),
                               best, atol=1e-5)


def test_backend_choice_is_checked():
    with pytest.raises(InputError, match='"tensorrt" is not one of onnxruntime, torch'):
        PipelineOptions(inference_backend='tensorrt')
    with pytest.raises(InputError, match='onnxruntime runs on the CPU only'):
        PipelineOptions(device='cuda')
    per_object = QNet(QNetConfig(OBJECTS, sharing='per_object')).eval()
    with pytest.raises(InputError, match='per_object Q-Net runs only on the torch backend'):
        QNetRotationEstimator(per_object, PipelineOptions())
    QNetRotationEstimator(per_object, TORCH)
