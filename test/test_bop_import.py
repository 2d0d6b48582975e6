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
Training where users train: annotated BOP images as caches, and the training device.

A BOP folder written by ``bbpose synth`` is imported and compared with the render cache of
the same scenes; half of its images are re-shot through another camera (zoomed, shifted,
JPEG, no ``bbox_obj``) to exercise per-image cameras and boxes projected from the mesh.
"""

import json
import shutil

import cv2
import numpy as np
import pytest
import torch

from bbpose_ros.cli.main import main
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.inference.weights import load_network
from bbpose_ros.core.synth import SyntheticScenes
from bbpose_ros.core.synth.crop_scenes import CropScenes
from bbpose_ros.core.training import cache as scene_cache
from bbpose_ros.core.training.cache import build_cache, TrainingCache, write_scene_shard
from bbpose_ros.core.training.crop_cache import build_crop_cache, CropCache
from bbpose_ros.core.training.device import training_device
from bbpose_ros.core.training.loop import RunLog
from bbpose_ros.core.util.errors import InputError

pytestmark = pytest.mark.slow   # renders with OpenGL and trains

SCENES = 6
SEED = 3
# Images 3.. are re-shot by a camera zoomed ZOOM times and shifted by SHIFT pixels.
ZOOM, SHIFT = 1.1, (32, 24)


def bbpose(*argv):
    """Run the ``bbpose`` command in-process; returns its exit code."""
    return main([str(a) for a in argv])


@pytest.fixture(scope='module')
def synth_folder(egl, tmp_path_factory, lmo_root):
    """``bbpose synth --count 6 --seed 3`` of all LM-O objects."""
    out = tmp_path_factory.mktemp('synth') / 'synth'
    code = bbpose('synth', '--dataset', lmo_root, '--out', out, '--count', SCENES,
                  '--seed', SEED, '--previews', 0)
    assert code == 0
    return out


@pytest.fixture(scope='module')
def render_cache(tmp_path_factory, lmo, lmo_models, synth_folder):
    """Build the render cache (``build_cache``) of the same scenes, in one shard."""
    folder = tmp_path_factory.mktemp('render') / 'scenes'
    scenes = SyntheticScenes(lmo_models, lmo.frames()[0].camera, seed=SEED)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(scene_cache, 'SHARD_SIZE', SCENES)
        build_cache(scenes, folder, SCENES, (320, 240), workers=1, progress=False)
    scenes.close()
    return folder


def reshoot(root, camera, image_ids):
    """Move images to scene 1 as a zoomed, shifted camera sees them: JPEG, no bbox_obj."""
    scene0, scene1 = root / 'train_synth' / '000000', root / 'train_synth' / '000001'
    (scene1 / 'rgb').mkdir(parents=True)
    files = ('scene_gt.json', 'scene_gt_info.json', 'scene_camera.json')
    old = [json.loads((scene0 / name).read_text()) for name in files]
    new = [{}, {}, {}]
    size = (round(camera.width * ZOOM), round(camera.height * ZOOM))
    big = camera.scaled(*size)
    other = CameraIntrinsics(big.fx, big.fy, big.cx - SHIFT[0], big.cy - SHIFT[1],
                             camera.width, camera.height)
    for image_id in image_ids:
        key = str(image_id)
        png = scene0 / 'rgb' / f'{image_id:06d}.png'
        shot = cv2.resize(cv2.imread(str(png)), size, interpolation=cv2.INTER_LINEAR)
        shot = shot[SHIFT[1]:SHIFT[1] + camera.height, SHIFT[0]:SHIFT[0] + camera.width]
        cv2.imwrite(str(scene1 / 'rgb' / f'{image_id:06d}.jpg'), shot,
                    [cv2.IMWRITE_JPEG_QUALITY, 95])
        png.unlink()
        new[0][key] = old[0].pop(key)
        new[1][key] = [{k: v for k, v in info.items() if k != 'bbox_obj'}
                       for info in old[1].pop(key)]
        new[2][key] = {'cam_K': other.k.reshape(-1).tolist(), 'depth_scale': 1.0}
        old[2].pop(key)
    for folder, contents in ((scene0, old), (scene1, new)):
        for name, data in zip(files, contents):
            (folder / name).write_text(json.dumps(data))


@pytest.fixture(scope='module')
def bop_folder(tmp_path_factory, synth_folder, lmo):
    """Copy the synth folder, images 3..5 re-shot by another camera as scene 1."""
    root = tmp_path_factory.mktemp('bop') / 'bop'
    shutil.copytree(synth_folder, root)
    reshoot(root, lmo.frames()[0].camera, range(3, SCENES))
    return root


@pytest.fixture(scope='module')
def imported(tmp_path_factory, lmo_root, bop_folder):
    """``bbpose train import-bop`` of the BOP folder into a scene cache."""
    cache = tmp_path_factory.mktemp('imported') / 'scenes'
    assert bbpose('train', 'import-bop', '--dataset', lmo_root, '--images', bop_folder,
                  '--split', 'train_synth', '--cache', cache, '--workers', 1) == 0
    return cache


def shard(folder):
    """Load all arrays of a cache folder's first shard."""
    return dict(np.load(folder / 'shard_00000.npz'))


def test_imported_images_have_the_render_caches_ground_truth(render_cache, imported):
    rendered, ours = shard(render_cache), shard(imported)
    assert sorted(ours) == sorted(rendered)
    for key in ('scene', 'object'):
        np.testing.assert_array_equal(ours[key], rendered[key])
    for key in ('visib', 'rotation', 'translation'):
        np.testing.assert_allclose(ours[key], rendered[key], atol=1e-6)
    # The PNG images of the cache camera are taken as they are.
    np.testing.assert_array_equal(ours['images'][:3], rendered['images'][:3])
    # Boxes: BOP's integer bbox_obj (within half a pixel), or projected from the mesh.
    png = ours['scene'] < 3
    np.testing.assert_allclose(ours['box_uv'][png], rendered['box_uv'][png], atol=0.5 + 1e-3)
    np.testing.assert_allclose(ours['box_uv'][~png], rendered['box_uv'][~png], atol=1e-3)
    # The re-shot JPEGs, resampled into the cache camera, show the same scene where the
    # other camera saw it (its narrower view leaves a grey border).
    inside = (slice(None), slice(16, 224), slice(20, 300))
    difference = np.abs(ours['images'][3:][inside].astype(float)
                        - rendered['images'][3:][inside])
    assert difference.mean() < 2.0
    assert np.all(ours['images'][3:, :, :8] == 128)
    # The same meta.json fields: the trainers and --extra-cache take both alike.
    render_meta = json.loads((render_cache / 'meta.json').read_text())
    meta = json.loads((imported / 'meta.json').read_text())
    assert set(render_meta) < set(meta) and meta['source']['frames'] == SCENES
    for key in ('objects', 'camera', 'input_size', 'crop_size', 'crop_context'):
        assert meta[key] == render_meta[key]
    mixed = TrainingCache([render_cache, imported])
    assert len(mixed.images) == 2 * SCENES


def test_a_shard_without_instances_keeps_the_arrays_types(render_cache, tmp_path):
    rendered = shard(render_cache)
    write_scene_shard(tmp_path / 'shard_00000.npz', [(rendered['images'][0], None)])
    empty = shard(tmp_path)
    assert sorted(empty) == sorted(rendered)
    assert len(empty['images']) == 1 and len(empty['object']) == 0
    for key, value in empty.items():
        assert (value.dtype, value.shape[1:]) == (rendered[key].dtype, rendered[key].shape[1:])


def test_an_import_resumes_and_refuses_other_settings(lmo_root, bop_folder, imported,
                                                      capsys):
    before = shard(imported)
    (imported / 'shard_00000.npz').unlink()
    command = ('train', 'import-bop', '--dataset', lmo_root, '--images', bop_folder,
               '--split', 'train_synth', '--cache', imported, '--workers', 1)
    assert bbpose(*command) == 0
    for key, value in shard(imported).items():
        np.testing.assert_array_equal(value, before[key])
    assert bbpose(*command, '--input-size', '160,128') == 2
    assert 'was built with other settings' in capsys.readouterr().err


def test_imported_crops_mix_with_rendered_crops(lmo_root, lmo, lmo_models, bop_folder,
                                                render_cache, tmp_path):
    crops = tmp_path / 'crops'
    assert bbpose('train', 'import-bop', '--dataset', lmo_root, '--images', bop_folder,
                  '--split', 'train_synth', '--cache', crops, '--kind', 'crops',
                  '--workers', 1) == 0
    cache = CropCache(crops)
    rendered = shard(render_cache)
    kept = rendered['visib'] >= 0.15
    assert cache.crop.shape == (int(kept.sum()), 64, 64, 3)
    np.testing.assert_array_equal(cache.object, rendered['object'][kept])
    np.testing.assert_allclose(cache.box_uv, rendered['box_uv'][kept], atol=0.5 + 1e-3)
    size = np.tile(cache.box_uv[:, 2:] - cache.box_uv[:, :2], 2)
    jitter = np.abs(cache.input_box_uv - cache.box_uv)
    assert np.all(jitter < 0.4 * size) and jitter.max() > 0
    rendered_crops = tmp_path / 'rendered_crops'
    scenes = CropScenes(lmo_models, lmo.frames()[0].camera, seed=SEED, box_sigma=0.06)
    build_crop_cache(scenes, rendered_crops, 4, workers=1, progress=False, shard_size=4)
    scenes.close()
    assert len(CropCache([rendered_crops, crops]).visib) == 4 + int(kept.sum())


def test_twenty_steps_on_an_imported_cache_lower_the_loss(lmo_root, imported, tmp_path):
    run = tmp_path / 'run'
    assert bbpose('train', 'detector', '--dataset', lmo_root, '--cache', imported,
                  '--run-dir', run, '--steps', 20, '--every', 10, '--lr', 0.05,
                  '--device', 'cpu') == 0
    first, last = RunLog(run).rows()
    assert last['loss'] < 0.8 * first['loss']
    network = load_network(run / 'detector.pt', 'detector')
    assert network.metadata['training']['device'] == 'cpu'


def test_evaluation_frames_are_never_imported(lmo_root, lmo_frames, synth_folder, tmp_path,
                                              capsys):
    cache = tmp_path / 'cache'
    assert bbpose('train', 'import-bop', '--dataset', lmo_root, '--images', lmo_root,
                  '--split', 'test', '--cache', cache) == 2
    error = capsys.readouterr().err
    assert 'refusing to import' in error and '100 of its images are evaluation frames' in error
    # A byte-identical copy under another name is the same frame.
    copy = tmp_path / 'copy'
    shutil.copytree(synth_folder, copy)
    target = copy / 'train_synth' / '000000' / 'rgb' / '000004.png'
    shutil.copyfile(lmo_frames[7].image_path, target)
    assert bbpose('train', 'import-bop', '--dataset', lmo_root, '--images', copy,
                  '--split', 'train_synth', '--cache', cache) == 2
    assert f'{target} is {lmo_frames[7].image_path}' in capsys.readouterr().err
    assert not cache.exists()


def test_the_device_is_cuda_when_torch_sees_one_and_cuda_needs_one(monkeypatch, lmo_root,
                                                                   imported, tmp_path,
                                                                   capsys):
    monkeypatch.setattr(torch.cuda, 'is_available', lambda: False)
    assert training_device(None) == torch.device('cpu')
    with pytest.raises(InputError, match='training device cuda is not available'):
        training_device('cuda')
    code = bbpose('train', 'detector', '--dataset', lmo_root, '--cache', imported,
                  '--run-dir', tmp_path / 'run', '--steps', 1, '--device', 'cuda')
    assert code == 2
    assert 'training device cuda is not available' in capsys.readouterr().err
    assert not (tmp_path / 'run').exists()
    monkeypatch.setattr(torch.cuda, 'is_available', lambda: True)
    assert training_device(None) == torch.device('cuda')
    assert training_device('cpu') == torch.device('cpu')


@pytest.mark.skipif(not torch.cuda.is_available(), reason='needs a CUDA GPU')
def test_a_cuda_checkpoint_resumes_on_the_cpu(lmo_root, imported, tmp_path):
    run = tmp_path / 'run'
    command = ('train', 'detector', '--dataset', lmo_root, '--cache', imported,
               '--run-dir', run, '--every', 2)
    assert bbpose(*command, '--steps', 4, '--device', 'cuda') == 0
    state = torch.load(run / 'checkpoint.pt', map_location='cpu', weights_only=True)
    devices = {t.device.type for t in state['network'].values()}
    assert devices == {'cpu'} and state['grad_scaler']['scale'] > 0
    assert bbpose(*command, '--steps', 6, '--device', 'cpu') == 0
    assert [r['step'] for r in RunLog(run).rows()] == [2, 4, 6]
    assert load_network(run / 'detector.pt', 'detector').metadata['training']['steps'] == 6


def test_a_missing_image_is_named_before_anything_is_written(lmo_root, synth_folder,
                                                             tmp_path, capsys):
    copy = tmp_path / 'copy'
    shutil.copytree(synth_folder, copy)
    missing = copy / 'train_synth' / '000000' / 'rgb' / '000002.png'
    missing.unlink()
    assert bbpose('train', 'import-bop', '--dataset', lmo_root, '--images', copy,
                  '--split', 'train_synth', '--cache', tmp_path / 'cache') == 2
    assert f'1 of the images of {copy / "train_synth"} are missing, e.g. {missing}' in \
        capsys.readouterr().err
    assert not (tmp_path / 'cache').exists()
