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

"""Training: a tiny run lowers the loss, checkpoints resume, batches are consistent."""

import json

import numpy as np
import pytest
import torch

from bbpose_ros.cli.main import main
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.rotations import quat_wxyz_to_matrix
from bbpose_ros.core.nets.crops import square_boxes
from bbpose_ros.core.nets.detector import CenterBoxNet, decode, DetectorConfig
from bbpose_ros.core.nets.qnet import QNet, QNetConfig
from bbpose_ros.core.nets.quaternion import symmetric_dot_product_loss
from bbpose_ros.core.synth.placement import viewpoint_angles, viewpoint_rotation
from bbpose_ros.core.training.cache import TrainingCache, whole_shards
from bbpose_ros.core.training.detector_training import DetectorBatches, DetectorTrainSettings
from bbpose_ros.core.training.device import TrainingDevice
from bbpose_ros.core.training.loop import run_loop, RunLog
from bbpose_ros.core.training.qnet_training import (inplane_deg, qnet_loss, QNetBatches,
                                                    QNetTrainSettings)
from bbpose_ros.core.training.runs import parameter_groups, train_detector, TrainingRun
from bbpose_ros.core.training.verifier_training import (candidate_targets, CandidateCrops,
                                                        verifier_step, verifier_validation,
                                                        VerifierBatches, VerifierTrainSettings)
from bbpose_ros.core.util.errors import InputError

OBJECTS = ('ape', 'can', 'cat', 'driller', 'duck', 'eggbox', 'glue', 'holepuncher')
CAMERA = CameraIntrinsics(572.4114, 573.57043, 325.2611, 242.04899, 640, 480)
CPU = TrainingDevice('cpu')


@pytest.mark.slow   # trains
@pytest.mark.parametrize('hypotheses', [1, 3])
def test_tiny_qnet_run_lowers_the_loss(hypotheses):
    torch.manual_seed(0)
    net = QNet(QNetConfig(OBJECTS[:2], channels=(8, 8, 16, 16), fc_size=32, dropout=0.0,
                          hypotheses=hypotheses))
    crops = torch.rand(16, 3, 48, 48)
    index = torch.arange(16) % 2
    target = torch.nn.functional.normalize(torch.randn(16, 1, 4), dim=-1)
    target = torch.where(target[..., :1] < 0, -target, target)
    valid = torch.ones(16, 1, dtype=torch.bool)
    optimizer = torch.optim.Adam(net.parameters(), 3e-3)
    losses = []
    for _ in range(60):
        loss = qnet_loss(net.hypotheses(crops, index), target, valid).mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(float(loss.detach()))
    assert np.mean(losses[-5:]) < 0.5 * np.mean(losses[:5])


def _step(optimizer, loss_fn):
    """Return a ``run_loop`` step: minimise ``loss_fn()`` once with ``optimizer``."""
    def step(_):
        loss = loss_fn()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        return float(loss.detach())
    return step


@pytest.mark.slow   # trains
def test_run_loop_checkpoints_and_resumes(tmp_path):
    net = torch.nn.Linear(2, 1)
    optimizer = torch.optim.SGD(net.parameters(), 0.1)
    step = _step(optimizer, lambda: net(torch.ones(1, 2)).pow(2).sum())
    exported = []
    assert run_loop(tmp_path, net, optimizer, step, 20, None, 0.1, every=5, progress=False,
                    on_checkpoint=exported.append, extra_state=None) == 20
    net2 = torch.nn.Linear(2, 1)
    optimizer2 = torch.optim.SGD(net2.parameters(), 0.1)
    assert run_loop(tmp_path, net2, optimizer2, step, 30, 0.0, 0.1, every=5,
                    progress=False) == 20   # zero seconds: resumes, then stops
    torch.testing.assert_close(net2.weight, net.weight)
    assert [r['step'] for r in RunLog(tmp_path).rows()] == [5, 10, 15, 20]
    assert exported == [5, 10, 15, 20]
    assert (tmp_path / 'loss.png').stat().st_size > 1000
    assert not (tmp_path / 'sim_to_real.png').exists()     # no real-frame figures logged


@pytest.mark.slow   # trains
def test_a_pretrained_trunk_learns_slower_on_its_imagenet_statistics(tmp_path):
    net = CenterBoxNet(DetectorConfig(OBJECTS[:2], backbone='lite0'))
    trunk = {id(p) for p in net.trunk.parameters()}
    head, scaled = parameter_groups(net, 0.1)
    assert scaled['lr_scale'] == 0.1 and {id(p) for p in scaled['params']} == trunk
    assert not trunk & {id(p) for p in head['params']}
    optimizer = torch.optim.AdamW([head, scaled], 1e-3)

    def loss():
        heat, sides = net(torch.rand(2, 3, 64, 64))
        return heat.square().mean() + sides.square().mean()

    step = _step(optimizer, loss)
    statistics = net.trunk._bn0.running_mean.clone()
    run_loop(tmp_path, net, optimizer, step, 3, None, 1e-3, every=3, progress=False)
    assert optimizer.param_groups[1]['lr'] == pytest.approx(0.1 * optimizer.param_groups[0]['lr'])
    assert torch.equal(net.trunk._bn0.running_mean, statistics)       # ImageNet's, kept
    assert net.training and not net.trunk._bn0.training and net.merge[0][1].training

    frozen = CenterBoxNet(DetectorConfig(OBJECTS[:2], backbone='lite0'))
    groups = parameter_groups(frozen, 0.0)
    assert len(groups) == 1 and not any(p.requires_grad for p in frozen.trunk.parameters())
    assert parameter_groups(CenterBoxNet(DetectorConfig(OBJECTS[:2])), 0.1)[0].keys() == {
        'params'}


def test_real_frame_figures_get_a_sim_to_real_chart(tmp_path):
    net = torch.nn.Linear(2, 1)
    optimizer = torch.optim.SGD(net.parameters(), 0.0)
    figures = {'val_loss': 0.1, 'val_median_deg': 30.0, 'real_median_deg': 45.0}
    run_loop(tmp_path, net, optimizer, lambda _: 1.0, 4, None, 0.0, validate=lambda: figures,
             every=2, progress=False)
    rows = RunLog(tmp_path).rows()
    assert [r['real_median_deg'] for r in rows] == [45.0, 45.0]
    assert (tmp_path / 'sim_to_real.png').stat().st_size > 1000


def _fake_cache(rng, scenes=2, per_scene=3):
    count = scenes * per_scene
    centre = rng.uniform([150, 120], [490, 360], (count, 2))
    half = rng.uniform(20, 80, (count, 2))
    boxes = np.concatenate([centre - half, centre + half], axis=1)
    q = rng.normal(size=(count, 4))
    cache = TrainingCache.__new__(TrainingCache)
    cache.__dict__.update(
        objects=list(OBJECTS), camera=CAMERA, input_size=(320, 240),
        images=rng.integers(0, 255, (scenes, 240, 320, 3), dtype=np.uint8),
        scene=np.repeat(np.arange(scenes), per_scene),
        object=np.arange(count) % len(OBJECTS), box_uv=boxes,
        visib=np.ones(count), rotation=quat_wxyz_to_matrix(q),
        crop=rng.integers(0, 255, (count, 128, 128, 3), dtype=np.uint8),
        square=square_boxes(boxes, 2.0))
    return cache


def _write_cache(folder, cache, camera=CAMERA):
    """Store a fake cache as a cache folder (meta.json and one shard)."""
    folder.mkdir()
    meta = {'objects': list(OBJECTS), 'camera': [camera.fx, camera.fy, camera.cx, camera.cy,
                                                 camera.width, camera.height],
            'input_size': [320, 240], 'crop_context': 2.0}
    (folder / 'meta.json').write_text(json.dumps(meta))
    np.savez(folder / 'shard_00000.npz', images=cache.images, scene=cache.scene,
             object=cache.object, box_uv=cache.box_uv, visib=cache.visib,
             rotation=cache.rotation, translation=np.zeros((len(cache.scene), 3)),
             crop=cache.crop, square=cache.square)


def test_training_cache_joins_folders_and_refuses_a_different_camera(tmp_path):
    rng = np.random.default_rng(4)
    first, second = _fake_cache(rng, scenes=2), _fake_cache(rng, scenes=3)
    _write_cache(tmp_path / 'a', first)
    _write_cache(tmp_path / 'b', second)
    joined = TrainingCache([tmp_path / 'a', tmp_path / 'b'])
    assert len(joined.images) == 5
    np.testing.assert_array_equal(joined.scene, np.concatenate([first.scene, second.scene + 2]))
    np.testing.assert_array_equal(joined.images[2:], second.images)
    other = CameraIntrinsics(500.0, 500.0, 320.0, 240.0, 640, 480)
    _write_cache(tmp_path / 'c', second, other)
    with pytest.raises(InputError, match='objects, camera or sizes differ'):
        TrainingCache([tmp_path / 'a', tmp_path / 'c'])
    (tmp_path / 'crops').mkdir()           # e.g. a Q-Net crop cache given by mistake
    (tmp_path / 'crops' / 'meta.json').write_text(json.dumps({'kind': 'qnet_crops'}))
    with pytest.raises(InputError, match='crops/meta.json is not a scene training cache'):
        TrainingCache([tmp_path / 'a', tmp_path / 'crops'])


def test_detector_targets_decode_to_the_boxes():
    cache = _fake_cache(np.random.default_rng(3))
    batches = DetectorBatches(cache, DetectorConfig(OBJECTS), DetectorTrainSettings(), 0)
    _, heat, sides, weight = batches.make(np.array([0]), 0.0)
    logits = torch.logit(heat[0].clamp(1e-4, 1 - 1e-4))
    classes, scores, boxes = decode(logits, sides[0], 8, 0.5, 1)
    ids = batches.by_scene[0]
    truth = batches.input_boxes(ids)
    for j, box in zip(ids, truth):
        k = list(classes).index(batches.class_of[cache.object[j]])
        np.testing.assert_allclose(boxes[k], box, atol=1e-3)
    assert float(weight.sum()) > 0


def _mined(scenes=4):
    cache = _fake_cache(np.random.default_rng(5), scenes=scenes)
    torch.manual_seed(0)
    network = CenterBoxNet(DetectorConfig(OBJECTS, verifier_channels=(8, 8, 16, 16)))
    settings = VerifierTrainSettings(batch=32, mined_per_class=2, val_fraction=0.25)
    return cache, network, settings, CandidateCrops(network, cache, settings, 0, CPU, False)


def test_candidate_crops_are_labelled_by_the_true_boxes():
    cache, network, settings, mined = _mined()
    assert mined.crops.shape[1:] == (32, 32, 3) and len(mined.labels) == len(mined.crops)
    for scene in range(len(cache.images)):
        ids = np.flatnonzero(cache.scene == scene)
        labels = mined.labels[mined.scene == scene]
        # Each scene's jittered true boxes come last, labelled with their class.
        assert labels[-len(ids):].tolist() == (cache.object[ids] + 1).tolist()
        # An untrained heatmap (near its 0.05 prior everywhere) gives 2 candidates a class.
        assert len(labels) == 2 * len(OBJECTS) + len(ids)


def test_candidate_targets_lead_to_the_true_box():
    truth = np.array([[100.0, 50.0, 140.0, 110.0]])
    boxes = np.array([[104.0, 50.0, 140.0, 106.0],      # IoU 0.84: positive
                      [120.0, 80.0, 160.0, 140.0],      # IoU 0.14: background
                      [100.0, 70.0, 140.0, 130.0]])     # IoU 0.50 >= 0.3: positive
    squares = square_boxes(boxes, 1.2)
    labels, corrections = candidate_targets(boxes, squares, truth, np.array([4]), 0.3)
    assert labels.tolist() == [5, 0, 5]
    side = squares[:, 2:3] - squares[:, 0:1]
    np.testing.assert_allclose((boxes + corrections * side)[[0, 2]], truth[[0, 0]], atol=1e-4)
    assert not corrections[1].any()


@pytest.mark.slow   # trains
def test_tiny_verifier_run_lowers_the_loss():
    _, network, settings, mined = _mined()
    batches = VerifierBatches(mined, settings, 0)
    settings.augment_strength = 0.0
    optimizer = torch.optim.Adam(network.verifier.parameters(), 3e-3)
    network.verifier.train()
    losses = [verifier_step(network.verifier, optimizer, batches, CPU) for _ in range(40)]
    assert np.mean(losses[-5:]) < 0.5 * np.mean(losses[:5])
    figures = verifier_validation(network.verifier, batches, CPU)
    assert 0 <= figures['val_accuracy'] <= 1 and np.isfinite(figures['val_loss'])


def test_qnet_batches_are_on_the_hemisphere(lmo_models):
    cache = _fake_cache(np.random.default_rng(4), scenes=4)
    config = QNetConfig(OBJECTS, rotation_target='allocentric')
    settings = QNetTrainSettings(batch=8, val_fraction=0.25)
    batches = QNetBatches(cache, config, lmo_models, settings, 0)
    images, index, candidates, valid = batches.train_batch()
    assert images.shape == (8, 3, 48, 48) and candidates.shape[:2] == valid.shape
    assert torch.all(candidates[..., 0] >= 0)
    assert set(batches.val_ids) & set(batches.train_ids) == set()


def test_viewpoint_angles_invert_viewpoint_rotation():
    rng = np.random.default_rng(8)
    angles = np.stack([rng.uniform(-np.pi, np.pi, 50), rng.uniform(-1.5, 1.5, 50),
                       rng.uniform(-np.pi, np.pi, 50)], axis=1)
    rotations = np.array([viewpoint_rotation(*a) for a in angles])
    np.testing.assert_allclose(np.stack(viewpoint_angles(rotations), axis=1), angles,
                               atol=1e-9)
    # Straight down the azimuth is undefined: it is 0 and the whole turn is in-plane.
    down = viewpoint_angles(viewpoint_rotation(0.0, np.pi / 2, 0.7)[None])
    np.testing.assert_allclose(np.ravel(down), [0.0, np.pi / 2, 0.7], atol=1e-9)


def test_max_inplane_keeps_only_upright_instances(lmo_models):
    cache = _fake_cache(np.random.default_rng(6), scenes=8, per_scene=8)
    roll = inplane_deg(cache)
    settings = QNetTrainSettings(batch=8, val_fraction=0.25, max_inplane_deg=60.0)
    batches = QNetBatches(cache, QNetConfig(OBJECTS), lmo_models, settings, 0)
    kept = np.concatenate([batches.train_ids, batches.val_ids])
    assert 0 < len(kept) < len(roll)
    np.testing.assert_array_equal(np.sort(kept), np.flatnonzero(np.abs(roll) <= 60.0))


@pytest.mark.parametrize('sign_invariant', [False, True])
def test_sign_invariant_loss_accepts_the_antipode(lmo_models, sign_invariant):
    cache = _fake_cache(np.random.default_rng(5), scenes=4)
    settings = QNetTrainSettings(batch=8, val_fraction=0.25, sign_invariant=sign_invariant)
    batches = QNetBatches(cache, QNetConfig(OBJECTS), lmo_models, settings, 0)
    _, _, candidates, valid = batches.train_batch()
    truth = candidates[:, 0]
    torch.testing.assert_close(symmetric_dot_product_loss(truth, candidates, valid),
                               torch.zeros(8))
    antipode_loss = symmetric_dot_product_loss(-truth, candidates, valid)
    if sign_invariant:
        torch.testing.assert_close(antipode_loss, torch.zeros(8), atol=1e-6, rtol=0)
    else:    # the paper's loss: -q is the worst answer, but for a symmetric equivalent
        assert torch.all(antipode_loss > 0.1)
        plain = valid.sum(dim=1) == 1
        assert plain.any()
        torch.testing.assert_close(antipode_loss[plain], torch.ones(int(plain.sum())))


def test_train_cli_without_a_cache_is_a_clear_error(tmp_path, lmo_root, capsys):
    code = main(['train', 'qnet', '--dataset', str(lmo_root), '--cache', str(tmp_path),
                 '--run-dir', str(tmp_path / 'run'), '--steps', '1'])
    assert code == 2
    assert 'no training cache' in capsys.readouterr().err


def test_render_crops_cli_counts_scenes_only_for_table_crops(tmp_path, lmo_root, capsys):
    common = ['train', 'render-crops', '--dataset', str(lmo_root), '--cache',
              str(tmp_path / 'crops')]
    assert main(common + ['--scene-style', 'table']) == 2
    assert '--scene-style table needs --scenes' in capsys.readouterr().err
    assert main(common + ['--scenes', '10']) == 2
    assert '--scenes is for --scene-style table' in capsys.readouterr().err
    assert not (tmp_path / 'crops').exists()


def test_a_render_says_when_it_rounds_up_to_whole_shards(capsys):
    assert whole_shards(500, 250) == 500 and capsys.readouterr().out == ''
    assert whole_shards(50, 250, 'crop') == 250
    assert capsys.readouterr().out == 'rendering 250 crops, not 50: whole shards of 250\n'


def test_train_detector_cli_joins_scene_caches_only(tmp_path, lmo_root, capsys):
    _write_cache(tmp_path / 'scenes', _fake_cache(np.random.default_rng(6)))
    (tmp_path / 'crops').mkdir()
    (tmp_path / 'crops' / 'meta.json').write_text(json.dumps({'kind': 'qnet_crops'}))
    code = main(['train', 'detector', '--dataset', str(lmo_root), '--cache',
                 str(tmp_path / 'scenes'), '--extra-cache', str(tmp_path / 'crops'),
                 '--run-dir', str(tmp_path / 'run'), '--steps', '1'])
    assert code == 2
    assert 'crops/meta.json is not a scene training cache' in capsys.readouterr().err
    assert not (tmp_path / 'run').exists()


def test_train_cli_refuses_zero_hypotheses(tmp_path, lmo_root, capsys):
    code = main(['train', 'qnet', '--dataset', str(lmo_root), '--cache', str(tmp_path),
                 '--run-dir', str(tmp_path / 'run'), '--steps', '1', '--hypotheses', '0'])
    assert code == 2
    assert '--hypotheses must be at least 1' in capsys.readouterr().err
    assert not (tmp_path / 'run').exists()


def test_train_verifier_cli_refuses_zero_candidates(tmp_path, lmo_root, capsys):
    code = main(['train', 'verifier', '--dataset', str(lmo_root), '--cache', str(tmp_path),
                 '--run-dir', str(tmp_path / 'run'), '--detector-weights',
                 str(tmp_path / 'detector.pt'), '--candidates', '0'])
    assert code == 2
    assert '--candidates must be at least 1' in capsys.readouterr().err
    assert not (tmp_path / 'run').exists()


def test_train_cli_refuses_a_window_or_input_size_off_the_grid(tmp_path, lmo_root, capsys):
    _write_cache(tmp_path / 'scenes', _fake_cache(np.random.default_rng(7)))
    code = main(['train', 'detector', '--dataset', str(lmo_root), '--cache',
                 str(tmp_path / 'scenes'), '--run-dir', str(tmp_path / 'run'), '--steps', '1',
                 '--backbone', 'lite0', '--train-crop', '400,160'])
    assert code == 2
    assert '--train-crop must be W,H in multiples of 16' in capsys.readouterr().err
    assert not (tmp_path / 'run').exists()
    code = main(['train', 'render', '--dataset', str(lmo_root), '--cache',
                 str(tmp_path / 'new'), '--scenes', '1', '--input-size', '330,240'])
    assert code == 2
    assert '--input-size must be W,H in positive multiples of 16' in capsys.readouterr().err
    assert not (tmp_path / 'new').exists()


@pytest.mark.slow   # trains
def test_a_resumed_run_keeps_its_own_trunk_rate_and_refuses_other_groups(tmp_path):
    def run(scales, steps):
        net = torch.nn.Sequential(torch.nn.Linear(2, 2), torch.nn.Linear(2, 1))
        groups = [{'params': list(layer.parameters()), 'lr_scale': scale}
                  for layer, scale in zip(net, scales)]
        optimizer = torch.optim.SGD(groups, 0.1)
        step = _step(optimizer, lambda: net(torch.ones(1, 2)).pow(2).sum())
        run_loop(tmp_path, net, optimizer, step, steps, None, 0.1, every=2, progress=False)
        return optimizer

    run([1.0, 0.1], 2)
    resumed = run([1.0, 0.5], 4)
    assert resumed.param_groups[1]['lr'] == pytest.approx(0.5 * resumed.param_groups[0]['lr'])
    with pytest.raises(InputError, match='other optimizer groups'):
        run([1.0], 6)


@pytest.mark.slow   # trains
def test_a_detector_run_can_start_from_a_trained_detector(tmp_path):
    cache = _fake_cache(np.random.default_rng(9), scenes=4)
    torch.manual_seed(1)
    trained = CenterBoxNet(DetectorConfig(OBJECTS))
    settings = DetectorTrainSettings(batch=2, lr=1e-12, val_fraction=0.25)
    tuned = train_detector(cache, DetectorConfig(OBJECTS), settings,
                           TrainingRun(tmp_path / 'run', 1, threads=1, progress=False),
                           init=trained)
    fresh = train_detector(cache, DetectorConfig(OBJECTS), settings,
                           TrainingRun(tmp_path / 'other', 1, threads=1, progress=False))
    # One step at a vanishing rate: the run holds the given weights, not new random ones.
    for (name, start), end, other in zip(trained.state_dict().items(),
                                         tuned.state_dict().values(),
                                         fresh.state_dict().values()):
        if start.is_floating_point() and 'running' not in name:
            assert torch.allclose(start, end, atol=1e-6), name
    assert any(not torch.allclose(a, b) for a, b in zip(trained.parameters(),
                                                        fresh.parameters()))
    with pytest.raises(InputError, match='network to start from does not fit'):
        train_detector(cache, DetectorConfig(OBJECTS[:4]), settings,
                       TrainingRun(tmp_path / 'third', 1, threads=1, progress=False),
                       init=trained)


@pytest.mark.parametrize('stage', ['render', 'render-crops'])
def test_table_options_are_refused_outside_table_scenes(tmp_path, lmo_root, capsys, stage):
    code = main(['train', stage, '--dataset', str(lmo_root), '--cache', str(tmp_path / 'c'),
                 '--mesh-brightness-range', '0.5,2', '--no-shadows', '--no-clutter'])
    assert code == 2
    assert ('--mesh-brightness-range, --no-shadows, --no-clutter: for --scene-style table, '
            'not random') in \
        capsys.readouterr().err
    assert not (tmp_path / 'c').exists()
