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

"""Dense correspondences: rendered coordinates, targets, the net, its loss and weight file."""

import json

import numpy as np
import pytest
import torch

from bbpose_ros.core.eval.metrics import cm_deg_errors
from bbpose_ros.core.geometry.boxes import box_centres
from bbpose_ros.core.geometry.dense_grid import cell_centres_uv, model_box
from bbpose_ros.core.geometry.dense_pnp import pose_from_dense_maps
from bbpose_ros.core.geometry.projection import projected_box_uv
from bbpose_ros.core.geometry.rotations import egocentric_to_allocentric
from bbpose_ros.core.inference.backends import make_runner
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.inference.weights import DEFAULT_DENSE_WEIGHTS, load_network, save_weights
from bbpose_ros.core.nets.crops import square_boxes
from bbpose_ros.core.nets.dense import DenseConfig, DenseNet
from bbpose_ros.core.pipeline.correspondences import (DenseCorrespondenceEstimator,
                                                      DenseStageSettings)
from bbpose_ros.core.pipeline.poses import Detection
from bbpose_ros.core.render import Draw, Lighting, MeshRenderer, RenderMesh
from bbpose_ros.core.synth.crop_scenes import CropScenes
from bbpose_ros.core.synth.dense_targets import dense_targets
from bbpose_ros.core.training.crop_cache import build_crop_cache, CropCache
from bbpose_ros.core.training.dense_training import (canonical_symmetry, dense_loss,
                                                     DenseBatches, DenseTrainSettings,
                                                     symmetric_coordinates)
from bbpose_ros.core.training.runs import train_dense, TrainingRun
from bbpose_ros.core.util.errors import InputError

pytestmark = pytest.mark.slow   # renders with OpenGL and trains

TARGETS = ('ape', 'eggbox', 'glue')


def _renderer(camera, models, names):
    renderer = MeshRenderer(camera, {n: RenderMesh.from_object_model(models[n]) for n in names})
    try:
        renderer.render([], Lighting())
    except RuntimeError as err:
        pytest.skip(f'headless OpenGL (EGL) unavailable: {err}')
    return renderer


@pytest.fixture(scope='module')
def dense_scenes(lmo_models, lmo_frames):
    """Build the CropScenes of TARGETS with 16 x 16 dense targets (96 px crops, render 192)."""
    scenes = CropScenes({n: lmo_models[n] for n in TARGETS}, lmo_frames[0].camera, seed=5,
                        crop_size=96, dense_size=16)
    _renderer(lmo_frames[0].camera, lmo_models, ['ape'])
    yield scenes
    scenes.close()


def _pnp_error(pose, rotation, translation, model):
    return cm_deg_errors(pose.rotation, pose.translation, rotation, translation,
                         model.symmetry_transforms)


def test_rendered_coordinates_give_back_the_pose(lmo_frames, lmo_models):
    # Every pixel of a real LM-O instance rendered at its ground truth pairs a pixel centre
    # with a model point: PnP over them recovers the pose.
    frame = lmo_frames[0]
    instance = next(i for i in frame.instances if i.object_name == 'driller')
    renderer = _renderer(frame.camera, lmo_models, ['driller'])
    rendered = renderer.render([Draw('driller', instance.rotation, instance.translation)],
                               Lighting(), coordinates=True)
    renderer.close()
    mask = rendered.instance_ids == 1
    rows, cols = np.nonzero(mask)
    points = rendered.model_coordinates[mask]
    model = lmo_models['driller']
    # The coordinates are model points: inside the model's box, and at the pose they lie on
    # the rays through their pixels.
    low, size = model_box(model.vertices)
    assert np.all(points >= low - 1e-4) and np.all(points <= low + size + 1e-4)
    uv = frame.camera.project(points @ instance.rotation.T + instance.translation)
    assert np.abs(uv - np.stack([cols, rows], 1)).max() < 0.05
    square = np.array([-0.5, -0.5, frame.camera.width - 0.5, frame.camera.width - 0.5])
    normalised = np.zeros((frame.camera.width, frame.camera.width, 3))
    probability = np.zeros(normalised.shape[:2])
    normalised[rows, cols] = (points - low) / size
    probability[rows, cols] = 1.0
    pose = pose_from_dense_maps(normalised, probability, square, frame.camera, low, size)
    re_deg, te_m = _pnp_error(pose, instance.rotation, instance.translation, model)
    assert pose.inliers == len(points) and re_deg < 0.01 and te_m < 1e-4


def test_crop_targets_give_back_the_pose_and_bound_the_masks(dense_scenes, lmo_models):
    for index in range(6):
        sample = dense_scenes.sample(index)
        model = lmo_models[sample.object_name]
        assert sample.coordinates.shape == (16, 16, 3)
        # The visible cells lie within the amodal silhouette.
        assert np.all(sample.visible_mask <= sample.amodal_mask + 1e-6)
        full = sample.visible_mask > 0.99
        if full.sum() < 8:
            continue
        pose = pose_from_dense_maps(sample.coordinates, full.astype(float), sample.square_uv,
                                    dense_scenes.camera, *model_box(model.vertices))
        re_deg, te_m = _pnp_error(pose, sample.rotation, sample.translation, model)
        assert re_deg < 1.0 and te_m < 0.003, (index, re_deg, te_m)
        # The amodal share is the whole silhouette: the box of its cells is the amodal box.
        cells = cell_centres_uv(sample.square_uv, 16)[sample.amodal_mask > 0.5]
        cell = (sample.square_uv[2] - sample.square_uv[0]) / 16
        assert np.all(cells.min(0) > sample.box_uv[:2] - cell)
        assert np.all(cells.max(0) < sample.box_uv[2:] + cell)


def test_symmetric_poses_get_one_canonical_target(lmo_frames, lmo_models):
    # The eggbox at a pose P and at P S (its symmetry) looks the same: both renders must
    # give the same target once canonicalised, although their raw coordinates differ.
    camera = lmo_frames[0].camera
    model = lmo_models['eggbox']
    symmetry = model.symmetry_transforms[1]
    renderer = _renderer(camera.cropped((0, 0, 1, 1), 128), lmo_models, ['eggbox'])
    rng = np.random.default_rng(0)
    low, size = model_box(model.vertices)
    for _ in range(4):
        axis = rng.normal(size=3)
        angle = rng.uniform(0, np.pi)
        rotation = _axis_angle(axis / np.linalg.norm(axis), angle)
        translation = np.array([0.05, -0.03, 0.8])
        box = projected_box_uv(camera, model.hull_points, rotation, translation)
        side = (box[2:] - box[:2]).max() * 1.2
        square = np.concatenate([(box[:2] + box[2:]) / 2 - side / 2,
                                 (box[:2] + box[2:]) / 2 + side / 2])
        targets, choices = [], []
        for pose_rotation, pose_translation in (
                (rotation, translation),
                (rotation @ symmetry[:3, :3], rotation @ symmetry[:3, 3] + translation)):
            rendered = renderer.render([Draw('eggbox', pose_rotation, pose_translation)],
                                       Lighting(), (0,), camera.cropped(square, 128), True)
            coordinates, visible, _ = dense_targets(rendered.model_coordinates,
                                                    rendered.instance_ids == 1,
                                                    rendered.full_masks[0], 16, low, size)
            allo = egocentric_to_allocentric(pose_rotation[None],
                                             camera.rays(box_centres(box)))
            k = canonical_symmetry(allo, model.symmetry_transforms[None, :, :3, :3])[0]
            choices.append(k)
            targets.append(symmetric_coordinates(coordinates, model.symmetry_transforms[k],
                                                 low, size) if k else coordinates)
        both = visible > 0.99
        raw_gap = np.abs(_raw(renderer, camera, square, rotation, translation, low, size)
                         - targets[0])
        assert choices[0] != choices[1]
        # models_info's symmetry is measured on the mesh: equal to about a millimetre.
        gap_mm = np.abs(targets[0] - targets[1])[both] * size * 1000
        assert np.median(gap_mm) < 1.5, np.median(gap_mm)
        assert raw_gap.max() < 1e-6 or choices[0] == 1
    renderer.close()


def _raw(renderer, camera, square, rotation, translation, low, size):
    rendered = renderer.render([Draw('eggbox', rotation, translation)], Lighting(), (0,),
                               camera.cropped(square, 128), True)
    return dense_targets(rendered.model_coordinates, rendered.instance_ids == 1,
                         rendered.full_masks[0], 16, low, size)[0]


def _axis_angle(axis, angle):
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def test_dense_cache_feeds_batches_and_a_version_1_cache_is_refused(
        dense_scenes, lmo_models, tmp_path, lmo_frames):
    build_crop_cache(dense_scenes, tmp_path / 'dense', 6, workers=1, progress=False,
                     shard_size=3)
    meta = json.loads((tmp_path / 'dense' / 'meta.json').read_text())
    assert meta['format_version'] == 2 and meta['dense_size'] == 16
    cache = CropCache(tmp_path / 'dense')
    assert cache.coordinates.shape == (6, 16, 16, 3) and cache.dense_size == 16
    np.testing.assert_allclose(cache.coordinates[4], dense_scenes.sample(4).coordinates,
                               atol=2e-3)
    config = DenseConfig(TARGETS, crop_size=32)
    settings = DenseTrainSettings(batch=4, val_fraction=0.34, min_visib=0.0)
    models = {n: lmo_models[n] for n in TARGETS}
    batches = DenseBatches(cache, config, models, settings, 0)
    images, index, coordinates, visible, amodal = batches.train_batch()
    assert images.shape == (4, 3, 32, 32) and coordinates.shape == (4, 3, 16, 16)
    assert visible.shape == amodal.shape == (4, 16, 16) and float(visible.max()) <= 1.0
    # A 48 px net (24 x 24 maps) reads the 16 x 16 targets resampled to its cells.
    wide = DenseBatches(cache, DenseConfig(TARGETS, crop_size=48), models, settings, 0)
    ids = np.arange(6)
    coarse, fine = batches.targets(ids), wide.targets(ids)
    assert fine[0].shape == (6, 24, 24, 3) and fine[1].shape == fine[2].shape == (6, 24, 24)
    for small, large in zip(coarse, fine):
        np.testing.assert_array_equal(large[:, ::3, ::3], small[:, ::2, ::2])
        np.testing.assert_array_equal(large[:, 1::3, 1::3], small[:, 1::2, 1::2])
    # A version-1 cache (no dense targets) still reads, for Q-Net, and is refused here.
    plain = CropScenes({n: lmo_models[n] for n in TARGETS}, lmo_frames[0].camera, seed=5,
                       crop_size=96)
    build_crop_cache(plain, tmp_path / 'plain', 2, workers=1, progress=False, shard_size=2)
    plain.close()
    assert 'format_version' not in json.loads((tmp_path / 'plain' / 'meta.json').read_text())
    old = CropCache(tmp_path / 'plain')
    assert old.dense_size == 0 and old.crop.shape == (2, 96, 96, 3)
    with pytest.raises(InputError, match='no dense targets'):
        DenseBatches(old, config, models, settings, 0)
    with pytest.raises(InputError, match='"dense_size" differs'):
        CropCache([tmp_path / 'dense', tmp_path / 'plain'])


def test_a_dense_run_can_start_from_a_trained_net(dense_scenes, lmo_models, tmp_path):
    build_crop_cache(dense_scenes, tmp_path / 'dense', 6, workers=1, progress=False,
                     shard_size=6)
    cache = CropCache(tmp_path / 'dense')
    config = DenseConfig(TARGETS, crop_size=32, channels=16)
    models = {n: lmo_models[n] for n in TARGETS}
    settings = DenseTrainSettings(batch=2, lr=1e-12, val_fraction=0.34, min_visib=0.0,
                                  augment='strong')
    torch.manual_seed(1)
    trained = DenseNet(config)
    tuned = train_dense(cache, models, config, settings,
                        TrainingRun(tmp_path / 'run', 1, threads=1, progress=False), init=trained)
    # One step at a vanishing rate: the run holds the given weights, not ImageNet's.
    for (name, start), end in zip(trained.state_dict().items(), tuned.state_dict().values()):
        if start.is_floating_point() and 'running' not in name:
            assert torch.allclose(start, end, atol=1e-6), name
    saved = torch.load(tmp_path / 'run' / 'dense.pt', weights_only=True)['metadata']
    assert saved['training']['settings']['augment'] == 'strong'
    with pytest.raises(InputError, match='network to start from does not fit'):
        train_dense(cache, models, DenseConfig(TARGETS, crop_size=32, channels=32), settings,
                    TrainingRun(tmp_path / 'other', 1, threads=1, progress=False), init=trained)


def test_dense_net_selects_its_class_and_the_loss_reaches_zero_at_the_target():
    torch.manual_seed(0)
    net = DenseNet(DenseConfig(('a', 'b', 'c'), crop_size=32, channels=16)).eval()
    crops = torch.rand(4, 3, 32, 32)
    with torch.no_grad():
        maps = net(crops, torch.tensor([0, 1, 2, 1]))
        every = [net(crops, torch.full((4,), k)) for k in range(3)]
    assert maps.shape == (4, 5, 16, 16)
    for row, k in enumerate([0, 1, 2, 1]):
        torch.testing.assert_close(maps[row], every[k][row])
    assert not torch.allclose(every[0], every[1])
    target = torch.rand(2, 3, 8, 8)
    visible = torch.zeros(2, 8, 8)
    visible[:, 2:6, 2:6] = 1.0
    logits = torch.where(visible > 0.5, 20.0, -20.0)
    perfect = torch.cat([target, logits[:, None], logits[:, None]], dim=1)
    loss, parts = dense_loss(perfect, target, visible, visible)
    assert float(loss.max()) < 1e-6
    # Coordinates off the visible cells do not count; off by 0.1 on them cost 0.1.
    shifted = perfect.clone()
    shifted[:, :3] += torch.where(visible[:, None] > 0.5, 0.1, 5.0)
    _, parts = dense_loss(shifted, target, visible, visible)
    torch.testing.assert_close(parts['coordinates'], torch.full((2,), 0.1))
    wrong = perfect.clone()
    wrong[:, 3] = -wrong[:, 3]
    assert float(dense_loss(wrong, target, visible, visible)[1]['visible'].min()) > 5.0


def test_dense_weights_round_trip_and_a_foreign_file_is_refused(tmp_path):
    torch.manual_seed(0)
    net = DenseNet(DenseConfig(('ape', 'glue'), crop_size=32, channels=16)).eval()
    path = tmp_path / 'dense.pt'
    save_weights(path, net, 'dense', {'command': 'test'})
    loaded = load_network(path, 'dense', objects=['glue'])
    crops = np.random.default_rng(0).integers(0, 255, (3, 32, 32, 3), dtype=np.uint8)
    index = np.array([0, 1, 1])
    torch_maps = make_runner(loaded, (crops, index),
                             PipelineOptions(inference_backend='torch'))(crops, index)
    onnx_maps = make_runner(loaded, (crops, index), PipelineOptions(),
                            dynamic_batch=True)(crops, index)
    torch.testing.assert_close(onnx_maps, torch_maps, atol=1e-4, rtol=1e-4)
    with pytest.raises(InputError, match='field "kind"'):
        load_network(path, 'qnet')
    with pytest.raises(InputError, match='field "objects" lacks cat'):
        load_network(path, 'dense', objects=['cat'])
    payload = torch.load(path, weights_only=True)
    payload['metadata']['coordinate_convention']['map_size'] = 32
    torch.save(payload, tmp_path / 'other.pt')
    with pytest.raises(InputError, match='field "coordinate_convention"'):
        load_network(tmp_path / 'other.pt', 'dense')


def test_pnp_needs_enough_masked_cells(lmo_frames):
    coordinates = np.random.default_rng(0).random((8, 8, 3))
    probability = np.zeros((8, 8))
    probability[0, :5] = 0.9
    assert pose_from_dense_maps(coordinates, probability, np.array([0, 0, 64, 64.0]),
                                lmo_frames[0].camera, np.zeros(3), np.ones(3)) is None


def test_the_stage_cuts_crops_as_qnet_and_solves_one_pose_each(lmo_frames, lmo_models):
    torch.manual_seed(0)
    frame = lmo_frames[0]
    net = DenseNet(DenseConfig(tuple(lmo_models), crop_size=32, channels=16)).eval()
    stage = DenseCorrespondenceEstimator(net, lmo_models, PipelineOptions())
    detections = [Detection(i.object_name, 1.0, i.box_uv) for i in frame.instances]
    maps, poses = stage(frame.load_image(), frame.camera, detections)
    count = len(detections)
    assert maps.coordinates.shape == (count, 16, 16, 3) and maps.visible.shape == (count, 16, 16)
    np.testing.assert_allclose(maps.squares_uv, square_boxes(
        np.array([d.box_uv for d in detections]), net.config.context))
    assert len(poses) == count
    empty, none = stage(frame.load_image(), frame.camera, [])
    assert empty.coordinates.shape == (0, 16, 16, 3) and none == []


def test_pnp_on_a_thread_pool_gives_the_poses_of_one_thread(lmo_frames, lmo_models):
    network = load_network(DEFAULT_DENSE_WEIGHTS, 'dense', list(lmo_models))
    frame = lmo_frames[0]
    detections = [Detection(i.object_name, 1.0, i.box_uv) for i in frame.instances
                  if np.all(np.isfinite(i.box_uv))]
    image = frame.load_image()
    _, alone = DenseCorrespondenceEstimator(network, lmo_models, PipelineOptions(),
                                            DenseStageSettings(pnp_threads=1))(
        image, frame.camera, detections)
    _, pooled = DenseCorrespondenceEstimator(network, lmo_models, PipelineOptions(),
                                             DenseStageSettings(pnp_threads=3))(
        image, frame.camera, detections)
    assert len(detections) >= 4 and sum(p is not None for p in alone) >= len(detections) - 1
    for one, other in zip(alone, pooled):
        assert (one is None) == (other is None)
        if one is not None:
            np.testing.assert_array_equal(one.rotation, other.rotation)
            np.testing.assert_array_equal(one.translation, other.translation)
    with pytest.raises(InputError, match=r'pnp_threads: -1 is out of range'):
        DenseStageSettings(pnp_threads=-1)


def test_the_stage_runs_on_some_of_its_objects(lmo_frames, lmo_models):
    network = load_network(DEFAULT_DENSE_WEIGHTS, 'dense', list(lmo_models))
    frame = lmo_frames[0]
    detection = next(Detection(i.object_name, 1.0, i.box_uv) for i in frame.instances
                     if np.all(np.isfinite(i.box_uv)))
    name = detection.object_name
    image = frame.load_image()
    alone = DenseStageSettings(pnp_threads=1)
    _, every = DenseCorrespondenceEstimator(network, lmo_models, PipelineOptions(),
                                            alone)(image, frame.camera, [detection])
    _, one = DenseCorrespondenceEstimator(network, {name: lmo_models[name]}, PipelineOptions(),
                                          alone)(image, frame.camera, [detection])
    assert every[0] is not None
    np.testing.assert_array_equal(every[0].rotation, one[0].rotation)
    np.testing.assert_array_equal(every[0].translation, one[0].translation)
    with pytest.raises(InputError, match='the dense net has no output for stranger'):
        DenseCorrespondenceEstimator(network, {'stranger': lmo_models[name]}, PipelineOptions())
