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

"""Synthetic scenes: self-consistent ground truth, determinism, the torch dataset."""

from dataclasses import replace

import numpy as np
import pytest

from bbpose_ros.core.geometry.boxes import mask_box_uv
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.projection import projected_box_uv
from bbpose_ros.core.geometry.rotations import egocentric_to_allocentric
from bbpose_ros.core.render.reference import render_silhouette
from bbpose_ros.core.synth import SynthConfig, SyntheticSample, SyntheticScenes
from bbpose_ros.core.synth.placement import viewpoint_angles
from bbpose_ros.core.synth.torch_dataset import SyntheticSceneDataset
from bbpose_ros.core.util.errors import InputError

pytestmark = pytest.mark.slow   # renders with OpenGL

CAMERA = CameraIntrinsics(572.4114, 573.57043, 325.2611, 242.04899, 640, 480)
TARGETS = ('ape', 'cat', 'duck', 'glue', 'holepuncher')


def make_scenes(lmo_models, seed, config=None):
    """Build the scenes of TARGETS with the other LM-O objects as distractors."""
    return SyntheticScenes({name: lmo_models[name] for name in TARGETS}, CAMERA, seed, config,
                           {n: m for n, m in lmo_models.items() if n not in TARGETS})


@pytest.fixture(scope='module')
def scenes(egl, lmo_models):
    """Build the scenes of seed 7."""
    scenes = make_scenes(lmo_models, 7)
    yield scenes
    scenes.close()


@pytest.fixture(scope='module')
def samples(scenes):
    """Render the first three samples of seed 7."""
    return [scenes.sample(i) for i in range(3)]


def test_ground_truth_is_self_consistent(samples, lmo_models):
    config = SynthConfig()
    count = 0
    for sample in samples:
        assert isinstance(sample, SyntheticSample)
        assert sample.image_rgb.shape == (480, 640, 3) and sample.image_rgb.dtype == np.uint8
        masks = np.stack([instance.mask for instance in sample.instances])
        assert masks.sum(axis=0).max() <= 1  # each pixel shows at most one object
        for instance in sample.instances:
            count += 1
            model = lmo_models[instance.object_name]
            assert instance.object_name in TARGETS
            np.testing.assert_allclose(instance.rotation @ instance.rotation.T, np.eye(3),
                                       atol=1e-9)
            assert np.linalg.det(instance.rotation) == pytest.approx(1.0)
            distance = np.linalg.norm(instance.translation)
            assert config.distance_range[0] - 1e-9 <= distance <= config.distance_range[1]
            # The amodal box is exactly the extremes of all projected vertices.
            np.testing.assert_allclose(instance.box_uv, projected_box_uv(
                CAMERA, model.vertices, instance.rotation, instance.translation), atol=1e-6)
            assert 0.0 < instance.visib_fract <= 1.0
            assert instance.mask.shape == (480, 640) and instance.mask.any()
            visible = mask_box_uv(instance.mask)
            assert np.all(visible[:2] >= instance.box_uv[:2] - 0.5)
            assert np.all(visible[2:] <= instance.box_uv[2:] + 0.5)
    assert count >= 6


def test_visib_fract_matches_reference(samples, lmo_models):
    checked = 0
    for sample in samples:
        for instance in sample.instances:
            box = instance.box_uv
            if box[0] < 0 or box[1] < 0 or box[2] > 639 or box[3] > 479:
                continue  # the reference renders inside the image only
            model = lmo_models[instance.object_name]
            full = render_silhouette(CAMERA, model.vertices, model.faces, instance.rotation,
                                     instance.translation)
            assert not (instance.mask & ~full).sum() > 2
            assert instance.visib_fract == pytest.approx(instance.mask.sum() / full.sum(),
                                                         abs=0.01)
            checked += 1
    assert checked >= 3


def test_fully_visible_object(lmo_models, scenes):
    lone = SyntheticScenes({'duck': lmo_models['duck']}, CAMERA, 3, replace(
        SynthConfig(), targets_per_image=(1, 1), distractors_per_image=(0, 0), frame_margin=0.0,
        distance_range=(0.8, 1.2)))
    try:
        for index in range(3):
            (instance,) = lone.sample(index).instances
            box = instance.box_uv
            if box[0] < 0 or box[1] < 0 or box[2] > 639 or box[3] > 479:
                continue
            assert instance.visib_fract == pytest.approx(1.0)
            np.testing.assert_allclose(mask_box_uv(instance.mask), box, atol=1.0)
    finally:
        lone.close()


def test_samples_are_deterministic(lmo_models, scenes, samples):
    again = make_scenes(lmo_models, 7)
    other = make_scenes(lmo_models, 8)
    try:
        for index in (2, 1):  # another order, another generator object
            first, second = samples[index], again.sample(index)
            np.testing.assert_array_equal(first.image_rgb, second.image_rgb)
            assert len(first.instances) == len(second.instances)
            for a, b in zip(first.instances, second.instances):
                assert a.object_name == b.object_name and a.visib_fract == b.visib_fract
                np.testing.assert_array_equal(a.rotation, b.rotation)
                np.testing.assert_array_equal(a.translation, b.translation)
                np.testing.assert_array_equal(a.box_uv, b.box_uv)
                np.testing.assert_array_equal(a.mask, b.mask)
        assert not np.array_equal(other.sample(1).image_rgb, samples[1].image_rgb)
    finally:
        again.close()
        other.close()


def test_torch_dataset_indexes_samples(scenes, samples):
    dataset = SyntheticSceneDataset(scenes, 2, transform=lambda s: len(s.instances))
    assert len(dataset) == 2
    assert dataset[1] == len(samples[1].instances)
    with pytest.raises(IndexError):
        dataset[2]


def test_inplane_range_bounds_the_roll_of_every_instance(lmo_models):
    config = SynthConfig(inplane_range_deg=(-20.0, 30.0), elevation_range_deg=(10.0, 60.0))
    scenes = make_scenes(lmo_models, 11, config)
    instances = [i for k in range(2) for i in scenes.sample(k).instances]
    scenes.close()
    rays = np.array([i.translation / np.linalg.norm(i.translation) for i in instances])
    allocentric = egocentric_to_allocentric(np.array([i.rotation for i in instances]), rays)
    _, elevation, inplane = np.degrees(viewpoint_angles(allocentric))
    assert len(instances) >= 8
    assert np.all((-20.0 - 1e-6 <= inplane) & (inplane <= 30.0 + 1e-6))
    assert np.all((10.0 - 1e-6 <= elevation) & (elevation <= 60.0 + 1e-6))


def test_bad_input_is_refused(lmo_models):
    with pytest.raises(InputError, match='distance_range'):
        SynthConfig(distance_range=(1.5, 0.35))
    with pytest.raises(InputError, match='inplane_range_deg'):
        SynthConfig(inplane_range_deg=(30.0, -30.0))
    with pytest.raises(InputError, match='jpeg_probability'):
        SynthConfig(jpeg_probability=2.0)
    with pytest.raises(InputError, match='both targets and distractors'):
        SyntheticScenes({'ape': lmo_models['ape']}, CAMERA, 0, None,
                        {'ape': lmo_models['ape']})
    with pytest.raises(InputError, match='seed'):
        SyntheticScenes({'ape': lmo_models['ape']}, CAMERA, -1)
