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

"""Q-Net: the q-normalization layer, the Dot Product Loss, symmetries and the hemisphere."""

import cv2
import numpy as np
import pytest
import torch

from bbpose_ros.core.geometry.boxes import box_centres
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.rotations import (matrix_to_quat_wxyz, quat_wxyz_to_matrix,
                                                ray_rotation, rotation_error_deg)
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.nets.crops import extract_crops, square_boxes
from bbpose_ros.core.nets.qnet import QNet, QNetConfig
from bbpose_ros.core.nets.quaternion import (multi_hypothesis_loss, QNormalization,
                                             symmetric_dot_product_loss)
from bbpose_ros.core.pipeline.poses import Detection
from bbpose_ros.core.pipeline.rotation_estimator import QNetRotationEstimator
from bbpose_ros.core.training.qnet_training import symmetry_rotations

OBJECTS = ('ape', 'can', 'cat', 'driller', 'duck', 'eggbox', 'glue', 'holepuncher')
CAMERA = CameraIntrinsics(572.4114, 573.57043, 325.2611, 242.04899, 640, 480)


def test_q_normalization_gradient_is_the_papers_formula():
    torch.manual_seed(0)
    raw = torch.randn(16, 4, dtype=torch.float64, requires_grad=True)
    target = torch.nn.functional.normalize(torch.randn(16, 4, dtype=torch.float64), dim=1)
    one_truth = torch.ones(16, 1, dtype=torch.bool)     # the paper's loss: one candidate
    symmetric_dot_product_loss(QNormalization()(raw), target[:, None], one_truth).sum().backward()
    q_raw = raw.detach()
    a = q_raw.norm(dim=1, keepdim=True)
    q_hat = q_raw / a
    # dq_hat_j / dQ_i = (1 - q_hat_i^2) / A for i == j, -q_hat_i q_hat_j / A otherwise.
    jacobian = (torch.eye(4, dtype=torch.float64) - q_hat[:, :, None] * q_hat[:, None, :])
    jacobian = jacobian / a[:, :, None]
    paper = -0.5 * torch.einsum('bj,bij->bi', target, jacobian)
    torch.testing.assert_close(raw.grad, paper)


@pytest.mark.parametrize('name', ['eggbox', 'glue'])
def test_symmetric_equivalent_gives_zero_loss(lmo_models, name):
    models = [lmo_models[n] for n in OBJECTS]
    rotations, valid = symmetry_rotations(models)
    k = OBJECTS.index(name)
    assert valid[k].sum() == len(lmo_models[name].symmetry_transforms) >= 2
    assert valid[OBJECTS.index('ape')].sum() == 1
    truth = quat_wxyz_to_matrix(np.array([0.8, 0.2, -0.5, 0.26]))
    candidates = torch.tensor(matrix_to_quat_wxyz(truth @ rotations[k]))[None].float()
    mask = torch.from_numpy(valid[k])[None]
    for s in np.flatnonzero(valid[k]):
        equivalent = truth @ lmo_models[name].symmetry_transforms[s, :3, :3]
        q_pred = torch.tensor(matrix_to_quat_wxyz(equivalent))[None].float()
        assert float(symmetric_dot_product_loss(q_pred, candidates, mask)) < 1e-6
        if s > 0:   # without the symmetry the same prediction is a large error
            plain = symmetric_dot_product_loss(q_pred, candidates[:, :1], mask[:, :1])
            assert float(plain) > 0.1


def test_targets_are_on_the_positive_hemisphere():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(100, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    targets = matrix_to_quat_wxyz(quat_wxyz_to_matrix(q))
    assert np.all(targets[:, 0] >= 0)
    same = np.isclose(np.abs(np.sum(targets * q, axis=1)), 1.0)
    assert same.all()
    # q and -q give one rotation: an output on the other hemisphere decodes the same.
    np.testing.assert_allclose(quat_wxyz_to_matrix(-q), quat_wxyz_to_matrix(q), atol=1e-12)


@pytest.mark.parametrize('crop_size', [48, 64])
@pytest.mark.parametrize('sharing', ['shared', 'per_object'])
@pytest.mark.parametrize('first_stride', [1, 2])
def test_qnet_outputs_unit_quaternions(crop_size, sharing, first_stride):
    config = QNetConfig(OBJECTS, crop_size=crop_size, sharing=sharing, first_stride=first_stride)
    net = QNet(config).eval()
    pools = [m for m in net.trunks[0] if isinstance(m, torch.nn.MaxPool2d)]
    assert len(pools) == len(config.channels) + 1 - first_stride
    crops = torch.rand(5, 3, crop_size, crop_size)
    with torch.inference_mode():
        q = net(crops, torch.tensor([0, 5, 6, 7, 0]))
    assert q.shape == (5, 4)
    torch.testing.assert_close(q.norm(dim=1), torch.ones(5))


def test_first_stride_is_checked():
    with pytest.raises(ValueError, match='first_stride'):
        QNetConfig(OBJECTS, first_stride=3)
    older = QNetConfig(OBJECTS).to_dict()
    del older['first_stride']    # weight files written before the option: the paper's stride
    assert QNetConfig.from_dict(older).first_stride == 1


def test_several_hypotheses_output_the_best_scored_one():
    net = QNet(QNetConfig(OBJECTS, first_stride=2, hypotheses=3)).eval()
    crops = torch.rand(6, 3, 48, 48)
    index = torch.tensor([0, 1, 2, 5, 6, 7])
    with torch.inference_mode():
        quats, scores = net.hypotheses(crops, index)
        output = net(crops, index)
    assert quats.shape == (6, 3, 4) and scores.shape == (6, 3)
    torch.testing.assert_close(quats.norm(dim=2), torch.ones(6, 3))
    torch.testing.assert_close(output, quats[torch.arange(6), scores.argmax(dim=1)])
    with pytest.raises(ValueError, match='hypotheses'):
        QNetConfig(OBJECTS, hypotheses=0)
    older = QNetConfig(OBJECTS).to_dict()
    del older['hypotheses']    # weight files written before the option: one quaternion
    assert QNetConfig.from_dict(older).hypotheses == 1


def test_winner_takes_all_loss():
    truth = torch.nn.functional.normalize(torch.tensor([[[0.9, 0.1, -0.3, 0.2]]]), dim=-1)
    valid = torch.ones(1, 1, dtype=torch.bool)
    wrong = torch.tensor([[[0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]]])
    quats = torch.cat([wrong[:, :1], truth, wrong[:, 1:]], dim=1)     # hypothesis 1 is right
    others = symmetric_dot_product_loss(wrong[0], truth.expand(2, 1, 4), valid.expand(2, 1))
    for scores, right in ((torch.tensor([[0.0, 9.0, 0.0]]), True),
                          (torch.tensor([[9.0, 0.0, 0.0]]), False)):
        loss = multi_hypothesis_loss(quats, scores, truth, valid, relax=0.1, score_weight=1.0)
        cross_entropy = torch.nn.functional.cross_entropy(scores, torch.tensor([1]))
        torch.testing.assert_close(loss, 0.05 * others.sum() + cross_entropy.view(1))
        assert (float(cross_entropy) < 1e-3) == right
    with pytest.raises(ValueError, match='at least 2 hypotheses'):
        multi_hypothesis_loss(truth, torch.zeros(1, 1), truth, valid)


def test_allocentric_output_is_turned_egocentric():
    net = QNet(QNetConfig(OBJECTS, rotation_target='allocentric')).eval()
    estimator = QNetRotationEstimator(net, PipelineOptions())
    image = np.random.default_rng(1).integers(0, 255, (480, 640, 3), dtype=np.uint8)
    box = np.array([40.0, 30.0, 120.0, 100.0])
    rotation = estimator(image, CAMERA, [Detection('ape', 1.0, box)])
    crops = extract_crops(image, square_boxes(box, net.config.context), 48)
    with torch.inference_mode():
        q = net(torch.from_numpy(crops).permute(0, 3, 1, 2).float() / 255, torch.tensor([0]))
    allo = quat_wxyz_to_matrix(q.numpy().astype(float))
    expected = ray_rotation(CAMERA.rays(box_centres(box))) @ allo
    assert rotation_error_deg(rotation, expected).max() < 1e-3
    assert rotation_error_deg(rotation, allo).max() > 5.0    # off-centre: the view matters


def test_square_crop_keeps_aspect_and_context():
    squares = square_boxes([[10.0, 20.0, 50.0, 100.0]], 1.2)
    np.testing.assert_allclose(squares, [[-18.0, 12.0, 78.0, 108.0]])
    image = np.zeros((480, 640, 3), dtype=np.uint8)
    crop = extract_crops(image, squares, 48)
    assert crop.shape == (1, 48, 48, 3)
    assert crop[0, 24, 0, 0] == 128 and crop[0, 24, 47, 0] == 0   # grey outside the image


@pytest.mark.parametrize('side', [40.0, 97.0, 150.0, 333.0])
def test_crop_shrinks_like_area_averaging_and_keeps_the_centre(side):
    rows, cols = np.mgrid[0:480, 0:640]
    image = np.repeat(((rows + 2 * cols) % 100).astype(np.uint8)[..., None], 3, axis=2)
    centre = np.array([300.0, 200.0])
    half = max(2, int(side / 16))    # a bright spot at the centre of the square
    image[200 - half:200 + half, 300 - half:300 + half] = 255
    squares = np.concatenate([centre - side / 2, centre + side / 2])[None]
    crop = extract_crops(image, squares, 48)[0, ..., 0].astype(float)
    rows_hit, cols_hit = np.nonzero(crop >= crop.max() - 1)
    np.testing.assert_allclose([cols_hit.mean(), rows_hit.mean()], [23.5, 23.5], atol=1.0)
    u0, v0 = (centre - side / 2).round().astype(int)
    region = image[v0:v0 + int(side), u0:u0 + int(side), 0]
    reference = cv2.resize(region, (48, 48), interpolation=cv2.INTER_AREA).astype(float)
    assert np.median(np.abs(crop - reference)) < 8.0
