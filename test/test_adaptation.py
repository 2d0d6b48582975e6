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

"""``bbpose adapt``: the gates, the label set, the students, and a run on real frames."""

import json
import shutil

import numpy as np
import pytest
import torch

from bbpose_ros.cli.common import in_blocks
from bbpose_ros.cli.main import main
from bbpose_ros.core.adaptation.adapt_stages import adapted_frames, read_rounds
from bbpose_ros.core.adaptation.frames import dataset_frames, image_fingerprint
from bbpose_ros.core.adaptation.label_set import IgnoreRegions, write_label_set
from bbpose_ros.core.adaptation.selection import select_labels, SelectionSettings, Verdict
from bbpose_ros.core.adaptation.students import adapt_detector, HeadTraining, ignore_mask
from bbpose_ros.core.adaptation.teacher import TeacherPose
from bbpose_ros.core.data.bop import BopDataset
from bbpose_ros.core.eval.label_precision import label_precision
from bbpose_ros.core.inference.weights import DEFAULT_DETECTOR_WEIGHTS, load_network
from bbpose_ros.core.training.cache import TrainingCache
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.ros.params import read_config
from bbpose_ros.ros.params_file import read_params_file

BOX = np.array([100.0, 100.0, 200.0, 180.0])


def _pose(name, confidence, translation, score=0.9, box=BOX):
    return TeacherPose(name, score, box, np.eye(3), np.asarray(translation, dtype=float),
                       confidence, box)


def test_thresholds_are_set_per_object_from_its_own_scores():
    frames = {str(k): [_pose('ape', 0.9 - 0.01 * k, [0, 0, 1]),
                       _pose('can', 0.7 - 0.01 * k, [0.2, 0, 1])] for k in range(10)}
    verdicts = select_labels(frames, SelectionSettings(keep=0.5, min_confidence=0.0,
                                                       consistency_mm=0.0))
    for name in ('ape', 'can'):
        kept = [k for k, judged in verdicts.items() for v in judged
                if v.pose.object_name == name and v.accepted]
        assert sorted(map(int, kept)) == [0, 1, 2, 3, 4]       # its best half
    floor = select_labels(frames, SelectionSettings(keep=1.0, min_confidence=0.65,
                                                    consistency_mm=0.0))
    assert all(v.verdict == 'confidence' for judged in floor.values() for v in judged
               if v.pose.object_name == 'can' and v.pose.confidence < 0.65)


def test_a_pose_that_breaks_the_static_scene_is_refused_and_low_scores_are_ignored():
    frames = {str(k): [_pose('ape', 0.9, [0, 0, 1]), _pose('can', 0.9, [0.2, 0, 1]),
                       _pose('cat', 0.9, [0, 0.2, 1])] for k in range(6)}
    frames['5'][0] = _pose('ape', 0.9, [0, 0, 1.3])           # 300 mm too far
    frames['4'].append(_pose('duck', 0.9, [0.1, 0.1, 1], score=0.1))
    verdicts = select_labels(frames, SelectionSettings(keep=1.0, min_confidence=0.5,
                                                       consistency_mm=60.0))
    assert [v.verdict for v in verdicts['5']] == ['consistency', 'accepted', 'accepted']
    assert [v.verdict for v in verdicts['4']] == ['accepted'] * 3 + ['detection']
    loose = select_labels(frames, SelectionSettings(keep=1.0, consistency_mm=0.0))
    assert loose['5'][0].accepted


def test_blocks_keep_whole_runs_of_consecutive_frames():
    frames = list(range(100))
    assert in_blocks(frames, {2, 4}, 20) == list(range(20, 40)) + list(range(60, 80))
    assert in_blocks(frames, None, 20) == frames
    with pytest.raises(InputError, match='--blocks 6'):
        in_blocks(frames, {6}, 20)


def test_the_fingerprint_names_the_pixels():
    image = np.zeros((4, 6, 3), np.uint8)
    changed = image.copy()
    changed[1, 2, 0] = 1
    assert image_fingerprint(image) == image_fingerprint(image.copy())
    assert image_fingerprint(image) != image_fingerprint(changed)
    assert image_fingerprint(image) != image_fingerprint(image.reshape(6, 4, 3))


@pytest.fixture(scope='module')
def unlabelled(lmo_root, tmp_path_factory):
    """Copy the first 20 LM-O frames into a BOP folder without scene_gt*.json."""
    root = tmp_path_factory.mktemp('unlabelled')
    for name in ('camera.json', 'models'):
        (root / name).symlink_to(lmo_root / name)
    source = next((lmo_root / 'test').iterdir())
    scene = root / 'test' / source.name
    (scene / 'rgb').mkdir(parents=True)
    cameras = json.loads((source / 'scene_camera.json').read_text())
    keep = sorted(cameras, key=int)[:20]
    (scene / 'scene_camera.json').write_text(json.dumps({k: cameras[k] for k in keep}))
    for key in keep:
        shutil.copy(source / 'rgb' / f'{int(key):06d}.png', scene / 'rgb')
    return root


@pytest.fixture(scope='module')
def adapted(unlabelled, tmp_path_factory):
    out = tmp_path_factory.mktemp('adapted') / 'out'
    assert main(['adapt', '--dataset', str(unlabelled), '--out', str(out), '--rounds', '1',
                 '--threads', '2']) == 0
    return out


@pytest.mark.slow
def test_adapt_writes_a_folder_the_node_loads_from_unlabelled_frames(unlabelled, adapted):
    values = read_params_file(adapted / 'params.yaml')
    config = read_config(values)
    assert config.detector_weights == (adapted / 'detector.pt').resolve()
    assert config.qnet_weights == (adapted / 'qnet.pt').resolve()
    frames = dataset_frames(unlabelled)
    fingerprints = {image_fingerprint(f.read()) for f in frames}
    assert adapted_frames(adapted / 'detector.pt', 'detector') == fingerprints
    assert adapted_frames(adapted / 'qnet.pt', 'qnet') == fingerprints
    report = json.loads((adapted / 'report.json').read_text())
    accepted = sum(c['accepted'] for c in report['labels']['round1'].values())
    assert accepted > 0
    labels = BopDataset(adapted / 'pseudo_labels').frames()
    assert sum(len(f.instances) for f in labels) == accepted
    for name in ('detector_int8.onnx', 'qnet_int8.onnx', 'preview.png'):
        assert (adapted / name).stat().st_size > 0
    # Only the box head learned: the heatmap is the shipped one.
    base = load_network(DEFAULT_DETECTOR_WEIGHTS, 'detector')
    student = load_network(adapted / 'detector.pt', 'detector')
    assert torch.equal(base.heatmap.weight, student.heatmap.weight)
    assert not torch.equal(base.box.weight, student.box.weight)


@pytest.mark.slow
def test_a_second_run_resumes_and_eval_refuses_the_adapted_frames(unlabelled, adapted,
                                                                  lmo_root, capsys):
    before = (adapted / 'qnet.pt').stat().st_mtime_ns
    assert main(['adapt', '--dataset', str(unlabelled), '--out', str(adapted),
                 '--rounds', '1']) == 0
    assert (adapted / 'qnet.pt').stat().st_mtime_ns == before
    assert 'done before' in capsys.readouterr().out
    assert main(['adapt', '--dataset', str(unlabelled), '--out', str(adapted),
                 '--rounds', '2']) == 2                  # other settings: refused
    params = str(adapted / 'params.yaml')
    assert main(['eval', '--dataset', str(lmo_root), '--max-frames', '3',
                 '--params', params]) == 2
    assert 'adapted on 3 of these frames' in capsys.readouterr().err


@pytest.mark.slow
def test_the_labels_are_mostly_right_on_the_frames_they_came_from(adapted, lmo_root, lmo,
                                                                  lmo_models):
    verdicts = read_rounds(adapted)['round1']
    figures = label_precision(verdicts, lmo.frames(), lmo_models)
    accepted = figures['accepted_all']
    refused = figures['verdicts']['confidence']
    assert accepted['right'] > 0.6 and accepted['box_iou_median'] > 0.8
    assert accepted['right'] > refused['right']


def test_untrusted_regions_are_left_out_of_the_heatmap_loss(lmo_root, tmp_path):
    network = load_network(DEFAULT_DETECTOR_WEIGHTS, 'detector')
    frames = dataset_frames(lmo_root)[:2]
    verdicts = {frames[0].key: [Verdict(_pose('ape', 0.9, [0, 0, 1]), 'accepted'),
                                Verdict(_pose('can', 0.2, [0, 0, 1],
                                              box=np.array([300., 200., 380., 300.])),
                                        'confidence')]}
    cache = write_label_set(tmp_path / 'labels', frames, verdicts, network.config.objects,
                            network.config.input_size)
    regions = IgnoreRegions.read(tmp_path / 'labels')
    counted = ignore_mask(regions, np.array([0]), network, cache)
    can = network.config.objects.index('can')
    assert len(cache.images) == 1 and len(cache.object) == 1
    assert not counted[0, can].all() and counted[0, can - 1].all()
    # In the detector's 480 px wide input, the can's box spans columns 225..285.
    stride = network.config.stride
    assert not counted[0, can, 160 // stride, 250 // stride]
    assert counted[0, can, 160 // stride, 100 // stride]
    figures = adapt_detector(network, TrainingCache(tmp_path / 'labels'), regions,
                             HeadTraining(steps=20, passes=1), progress=False)
    assert figures['loss_after'] < figures['loss_before']


@pytest.mark.slow
def test_a_bag_adapts_and_its_frames_are_known_by_their_pixels(lmo_root, tmp_path):
    bag, out = tmp_path / 'bag', tmp_path / 'out'
    assert main(['make-bag', '--dataset', str(lmo_root), '--out', str(bag),
                 '--max-frames', '6']) == 0
    assert main(['adapt', '--bag', str(bag), '--out', str(out), '--rounds', '1']) == 0
    images = {image_fingerprint(f.read()) for f in dataset_frames(lmo_root)[:6]}
    assert adapted_frames(out / 'qnet.pt', 'qnet') == images
    assert main(['adapt', '--bag', str(bag), '--out', str(tmp_path / 'other'),
                 '--image-topic', '/nothing']) == 2
