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

"""Weight files: round trip, metadata checks, refusal of corrupt or foreign files."""

import pytest
import torch

from bbpose_ros.core.inference.weights import (DEFAULT_DETECTOR_WEIGHTS, DEFAULT_QNET_WEIGHTS,
                                               load_network, save_weights)
from bbpose_ros.core.nets.detector import CenterBoxNet, DetectorConfig
from bbpose_ros.core.nets.efficientnet_lite import load_imagenet_trunks
from bbpose_ros.core.nets.qnet import QNet, QNetConfig
from bbpose_ros.core.util.errors import InputError

OBJECTS = ('ape', 'can', 'cat', 'driller', 'duck', 'eggbox', 'glue', 'holepuncher')
TRAINING = {'command': 'test', 'git_commit': 'abc', 'steps': 0}


@pytest.fixture
def qnet_file(tmp_path):
    path = tmp_path / 'qnet.pt'
    save_weights(path, QNet(QNetConfig(OBJECTS, rotation_target='allocentric')), 'qnet',
                 TRAINING)
    return path


def test_round_trip_keeps_weights_and_metadata(qnet_file):
    net = load_network(qnet_file, 'qnet', ['ape', 'glue'])
    assert net.config.rotation_target == 'allocentric'
    assert net.metadata['rotation_convention']['quaternion_order'] == 'wxyz'
    assert net.metadata['input_size'] == [48, 48]
    assert net.metadata['training']['git_commit'] == 'abc'
    reference = torch.load(qnet_file, weights_only=True)['state_dict']
    for key, value in net.state_dict().items():
        torch.testing.assert_close(value, reference[key])


def _rewrite(path, change):
    payload = torch.load(path, weights_only=True)
    change(payload)
    torch.save(payload, path)


@pytest.mark.parametrize('field, change', [
    ('format_version', lambda p: p['metadata'].update(format_version=99)),
    ('kind', lambda p: p['metadata'].update(kind='detector')),
    ('objects', lambda p: p['metadata'].update(objects=['ape'])),
    ('input_size', lambda p: p['metadata'].update(input_size=[64, 64])),
    ('rotation_convention', lambda p: p['metadata']['rotation_convention'].update(
        quaternion_order='xyzw')),
    ('architecture', lambda p: p['metadata']['architecture'].update(sharing='bogus')),
    ('state_dict', lambda p: p['state_dict'].pop('head.weight')),
    ('metadata', lambda p: p.pop('metadata')),
])
def test_mismatched_metadata_is_refused(qnet_file, field, change):
    _rewrite(qnet_file, change)
    with pytest.raises(InputError, match=field) as error:
        load_network(qnet_file, 'qnet')
    assert str(qnet_file) in str(error.value)


def test_wrong_expectations_are_refused(qnet_file):
    with pytest.raises(InputError, match='rotation_convention.target'):
        load_network(qnet_file, 'qnet', rotation_target='egocentric')
    with pytest.raises(InputError, match='"objects" lacks lamp'):
        load_network(qnet_file, 'qnet', ['ape', 'lamp'])
    with pytest.raises(InputError, match='"kind"'):
        load_network(qnet_file, 'detector')


def test_corrupt_and_missing_files_are_refused(tmp_path, qnet_file):
    broken = tmp_path / 'broken.pt'
    broken.write_bytes(qnet_file.read_bytes()[:1000])
    with pytest.raises(InputError, match='corrupt weight file .*broken.pt'):
        load_network(broken, 'qnet')
    with pytest.raises(InputError, match='not found'):
        load_network(tmp_path / 'absent.pt', 'qnet')


def test_detector_round_trip(tmp_path):
    path = tmp_path / 'detector.pt'
    save_weights(path, CenterBoxNet(DetectorConfig(OBJECTS)), 'detector', TRAINING)
    net = load_network(path, 'detector', OBJECTS)
    assert net.metadata['input_size'] == [320, 240]


def test_detector_with_second_stage_round_trip(tmp_path):
    path = tmp_path / 'detector.pt'
    config = DetectorConfig(OBJECTS, verifier_channels=(4, 8, 8, 8), candidates=3)
    net = CenterBoxNet(config).eval()
    save_weights(path, net, 'detector', TRAINING)
    loaded = load_network(path, 'detector', OBJECTS)
    assert loaded.config == config
    crops = torch.rand(2, 3, 32, 32)
    with torch.inference_mode():
        torch.testing.assert_close(loaded.verifier.outputs(crops), net.verifier.outputs(crops))


def test_detector_file_without_newer_fields_loads_as_one_scratch_stage(tmp_path):
    path = tmp_path / 'detector.pt'
    save_weights(path, CenterBoxNet(DetectorConfig(OBJECTS)), 'detector', TRAINING)
    payload = torch.load(path, weights_only=True)
    for key in ('verifier_channels', 'verifier_crop_size', 'verifier_context', 'candidates',
                'candidate_threshold', 'backbone', 'head_channels'):
        del payload['metadata']['architecture'][key]     # as files written before them
    torch.save(payload, path)
    loaded = load_network(path, 'detector', OBJECTS)
    assert loaded.verifier is None and loaded.config.backbone == 'scratch'


@pytest.mark.parametrize('kind', ['detector', 'qnet'])
def test_a_pretrained_trunk_travels_in_the_weight_file(tmp_path, kind):
    """A 'lite0' network loads from its own file alone: no ImageNet file is read."""
    if kind == 'detector':
        net = CenterBoxNet(DetectorConfig(OBJECTS, backbone='lite0'))
    else:
        net = QNet(QNetConfig(OBJECTS, crop_size=64, backbone='lite0', hypotheses=4))
    load_imagenet_trunks(net)
    net.eval()
    path = tmp_path / f'{kind}.pt'
    save_weights(path, net, kind, TRAINING)
    loaded = load_network(path, kind, OBJECTS)
    assert loaded.config.backbone == 'lite0'
    for key, value in net.state_dict().items():
        assert torch.equal(loaded.state_dict()[key], value), key


def test_shipped_weights_load():
    detector = load_network(DEFAULT_DETECTOR_WEIGHTS, 'detector', OBJECTS)
    qnet = load_network(DEFAULT_QNET_WEIGHTS, 'qnet', OBJECTS)
    for net, path in ((detector, DEFAULT_DETECTOR_WEIGHTS), (qnet, DEFAULT_QNET_WEIGHTS)):
        assert net.metadata['training']['command']
        assert path.stat().st_size < 8e6
