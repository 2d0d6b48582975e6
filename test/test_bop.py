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

"""The BOP reader on the real LM-O frames, and its errors on broken copies."""

import json
import shutil

import numpy as np
import pytest

from bbpose_ros.core.data.bop import BopDataset
from bbpose_ros.core.data.models import load_bop_models, load_mesh
from bbpose_ros.core.util.errors import InputError


def test_reads_frames_ground_truth_and_intrinsics(lmo, lmo_frames):
    assert len(lmo_frames) == 100
    camera = json.loads((lmo.root / 'camera.json').read_text())
    frame = lmo_frames[0]
    assert (frame.camera.fx, frame.camera.cy) == (camera['fx'], camera['cy'])
    assert frame.load_image().shape == (480, 640, 3)
    names = {i.object_name for f in lmo_frames for i in f.instances}
    assert names == {'ape', 'can', 'cat', 'driller', 'duck', 'eggbox', 'glue', 'holepuncher'}
    depths = np.array([i.translation[2] for f in lmo_frames for i in f.instances])
    assert 0.3 < depths.min() and depths.max() < 2.0          # metres, not millimetres
    # Rotations are read onto SO(3) (the file's matrices are not quite orthonormal), within
    # a fraction of a degree of the stored ones.
    scene_gt = json.loads((lmo.split_dir / f'{frame.scene_id:06d}' / 'scene_gt.json')
                          .read_text())[str(frame.image_id)]
    for instance, stored in zip(frame.instances, scene_gt):
        matrix = np.reshape(stored['cam_R_m2c'], (3, 3))
        np.testing.assert_allclose(instance.rotation @ instance.rotation.T, np.eye(3),
                                   atol=1e-12)
        assert abs(np.linalg.det(instance.rotation) - 1.0) < 1e-12
        np.testing.assert_allclose(instance.rotation, matrix, atol=5e-3)


def test_amodal_box_is_the_projected_model(lmo_frames, lmo_models):
    offsets = []
    for frame in lmo_frames[:30]:
        for instance in frame.instances:
            if np.isnan(instance.box_uv).any():      # BOP gives no box for hidden ones
                assert instance.visib_fract == 0.0
                continue
            model = lmo_models[instance.object_name]
            uv = frame.camera.project(model.vertices @ instance.rotation.T
                                      + instance.translation)
            offsets.append(np.r_[uv.min(axis=0), uv.max(axis=0)] - instance.box_uv)
    offsets = np.array(offsets)
    assert np.abs(offsets).max() < 1.0
    assert np.abs(offsets.mean(axis=0)).max() < 0.1


def test_models_are_in_metres_with_hull_and_symmetries(lmo_models):
    ape = lmo_models['ape']
    extent = np.linalg.norm(ape.vertices.max(axis=0) - ape.vertices.min(axis=0))
    assert ape.diameter == pytest.approx(0.102099)
    assert 0.5 * ape.diameter < extent < 1.5 * ape.diameter
    assert len(ape.hull_points) < len(ape.vertices)
    assert ape.box_corners.shape == (8, 3)
    assert [m.name for m in lmo_models.values() if m.is_symmetric] == ['eggbox', 'glue']


def broken_copy(lmo_root, tmp_path, scene_file=None, text=None):
    """Copy the dataset's JSON files (images and meshes linked), one file replaced."""
    root = tmp_path / 'lmo'
    shutil.copytree(lmo_root, root, symlinks=True,
                    copy_function=lambda src, dst: __import__('os').symlink(src, dst))
    if scene_file is not None:
        path = root / 'test' / '000002' / scene_file
        path.unlink()
        if text is not None:
            path.write_text(text)
    return root


def test_missing_folder_is_named(tmp_path):
    with pytest.raises(InputError, match='dataset folder not found: .*nowhere'):
        BopDataset(tmp_path / 'nowhere')


def test_malformed_json_is_named(lmo_root, tmp_path):
    root = broken_copy(lmo_root, tmp_path, 'scene_gt.json', '{"3": [')
    with pytest.raises(InputError, match='malformed JSON in .*scene_gt.json'):
        BopDataset(root).frames()


def test_missing_field_is_named(lmo_root, tmp_path):
    gt = json.loads((lmo_root / 'test/000002/scene_gt.json').read_text())
    del gt['3'][0]['cam_t_m2c']
    root = broken_copy(lmo_root, tmp_path, 'scene_gt.json', json.dumps(gt))
    with pytest.raises(InputError, match='image 3 instance 0 has no valid "cam_t_m2c"'):
        BopDataset(root).frames()


def test_missing_image_is_named(lmo_root, tmp_path):
    root = broken_copy(lmo_root, tmp_path)
    (root / 'test/000002/rgb/000003.png').unlink()
    frame = BopDataset(root).frames()[0]
    with pytest.raises(InputError, match='missing or unreadable image: .*000003.png'):
        frame.load_image()


def test_empty_mesh_and_unknown_object_are_named(lmo_root, tmp_path):
    empty = tmp_path / 'empty.ply'
    empty.write_text('ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\n'
                     'property float y\nproperty float z\nend_header\n')
    with pytest.raises(InputError, match='empty.ply'):
        load_mesh(empty)
    with pytest.raises(InputError, match='unknown object name.*banana'):
        load_bop_models(lmo_root, ['ape', 'banana'])
