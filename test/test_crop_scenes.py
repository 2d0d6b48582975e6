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

"""Object-centred Q-Net crops: crop cameras, ground truth, the crop cache, real validation."""

import json
import shutil

import numpy as np
import pytest
import torch

from bbpose_ros.core.geometry.boxes import mask_box_uv
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.projection import projected_box_uv
from bbpose_ros.core.nets.crops import square_boxes
from bbpose_ros.core.nets.qnet import QNet, QNetConfig
from bbpose_ros.core.render.reference import render_silhouette
from bbpose_ros.core.synth.crop_scenes import CropScenes
from bbpose_ros.core.training.crop_cache import build_crop_cache, CropCache, is_crop_cache
from bbpose_ros.core.training.qnet_training import QNetBatches, QNetTrainSettings
from bbpose_ros.core.training.real_validation import RealCrops
from bbpose_ros.core.util.errors import InputError

pytestmark = pytest.mark.slow   # renders with OpenGL

CAMERA = CameraIntrinsics(572.4114, 573.57043, 325.2611, 242.04899, 640, 480)
TARGETS = ('ape', 'driller', 'eggbox')


@pytest.fixture(scope='module')
def crop_scenes(egl, lmo_models):
    """Build the CropScenes of TARGETS (seed 3, 64 px)."""
    scenes = CropScenes({n: lmo_models[n] for n in TARGETS}, CAMERA, seed=3,
                        box_sigma=0.05)
    yield scenes
    scenes.close()


def test_cropped_camera_maps_the_square_onto_the_crop():
    square = np.array([100.3, 50.7, 228.3, 178.7])
    crop = CAMERA.cropped(square, 64)
    points = np.array([[0.05, -0.02, 0.8], [-0.1, 0.07, 1.2]])
    full_uv = CAMERA.project(points)
    expected = (full_uv - square[:2]) * 64 / 128.0 - 0.5
    np.testing.assert_allclose(crop.project(points), expected, atol=1e-9)
    # The square's edges are the crop's outer pixel edges.
    np.testing.assert_allclose(crop.normalized(np.array([-0.5, 63.5])),
                               CAMERA.normalized(square[[0, 3]]), atol=1e-12)


def test_crop_silhouette_matches_the_numpy_oracle(crop_scenes, lmo_models):
    model = lmo_models['driller']
    for index in (1, 4):
        sample = crop_scenes.sample(index)
        assert sample.object_name == TARGETS[index % len(TARGETS)]
    sample = crop_scenes.sample(1)
    camera = CAMERA.cropped(sample.square_uv, crop_scenes.render_size)
    oracle = render_silhouette(camera, model.vertices, model.faces, sample.rotation,
                               sample.translation)
    box = projected_box_uv(camera, model.hull_points, sample.rotation, sample.translation)
    # The oracle's silhouette touches the projected amodal box (within 1 render pixel).
    np.testing.assert_allclose(mask_box_uv(oracle), box, atol=1.0)
    # ... and that box is the sample's full-frame box seen through the crop camera.
    scale = crop_scenes.render_size / (sample.square_uv[2] - sample.square_uv[0])
    np.testing.assert_allclose((sample.box_uv - np.tile(sample.square_uv[:2], 2)) * scale
                               - 0.5, box, atol=1e-6)


def test_crop_samples_are_deterministic_and_consistent(crop_scenes, lmo_models):
    first, again = crop_scenes.sample(5), crop_scenes.sample(5)
    np.testing.assert_array_equal(first.image_rgb, again.image_rgb)
    for index in range(6):
        sample = crop_scenes.sample(index)
        model = lmo_models[sample.object_name]
        assert sample.image_rgb.shape == (64, 64, 3)
        assert crop_scenes.min_visib <= sample.visib_fract <= 1.0
        np.testing.assert_allclose(
            sample.box_uv, projected_box_uv(CAMERA, model.hull_points, sample.rotation,
                                            sample.translation), atol=1e-6)
        np.testing.assert_allclose(sample.square_uv,
                                   square_boxes(sample.input_box_uv, 1.2)[0], atol=1e-9)
        # The jitter is the detector-like error, a few percent of the box.
        size = np.tile(sample.box_uv[2:] - sample.box_uv[:2], 2)
        assert np.all(np.abs(sample.input_box_uv - sample.box_uv) < 0.4 * size)


def test_crop_cache_feeds_qnet_batches(crop_scenes, lmo_models, tmp_path):
    build_crop_cache(crop_scenes, tmp_path, 12, workers=1, progress=False, shard_size=6)
    assert is_crop_cache(tmp_path)
    cache = CropCache(tmp_path)
    assert cache.crop.shape == (12, 64, 64, 3) and cache.shards == 2
    np.testing.assert_array_equal(cache.crop[7], crop_scenes.sample(7).image_rgb)
    config = QNetConfig(TARGETS, rotation_target='allocentric')
    settings = QNetTrainSettings(batch=4, val_fraction=0.25, min_visib=0.0)
    batches = QNetBatches(cache, config, {n: lmo_models[n] for n in TARGETS}, settings, 0)
    images, index, candidates, valid = batches.train_batch()
    assert images.shape == (4, 3, 48, 48)
    assert torch.all(candidates[..., 0] >= 0) and candidates.shape[:2] == valid.shape
    assert set(batches.val_ids) == {9, 10, 11}
    # eggbox has two symmetric equivalents, the others one.
    eggbox = index == TARGETS.index('eggbox')
    assert torch.all(valid[eggbox].sum(dim=1) == 2) and torch.all(valid[~eggbox].sum(1) == 1)


def test_crop_caches_combine_and_refuse_mismatches(crop_scenes, tmp_path):
    first, second = tmp_path / 'a', tmp_path / 'b'
    build_crop_cache(crop_scenes, first, 4, workers=1, progress=False, shard_size=4)
    shutil.copytree(first, second)
    both = CropCache([first, second])
    assert len(both.visib) == 8 and list(both.folder) == [0] * 4 + [1] * 4
    assert list(np.flatnonzero(both.held_out(0.25))) == [3, 7]   # the last of each folder
    meta = json.loads((second / 'meta.json').read_text())
    meta['crop_size'] = 32
    (second / 'meta.json').write_text(json.dumps(meta))
    with pytest.raises(InputError, match='"crop_size" differs'):
        CropCache([first, second])
    with pytest.raises(InputError, match='no crop cache'):
        CropCache([first, tmp_path / 'missing'])


def test_real_crops_score_a_network_on_real_frames(lmo_frames, lmo_models):
    frames = lmo_frames[:3]
    real = RealCrops(frames, TARGETS, lmo_models)
    expected = sum(1 for f in frames for i in f.instances
                   if i.object_name in TARGETS and i.visib_fract >= 0.1)
    assert len(real) == expected > 0
    errors = real.rotation_errors(QNet(QNetConfig(TARGETS)))
    assert errors.shape == (expected,) and np.all((errors >= 0) & (errors <= 180))
    figures = real.figures(QNet(QNetConfig(TARGETS)))
    assert 0 <= figures['real_acc15'] <= figures['real_acc30'] <= 1
