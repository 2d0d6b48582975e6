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

"""``bbpose synth``: BOP output readable by our reader, atomic writes, clear input errors."""

import argparse
import json

import numpy as np
import pytest

from bbpose_ros.bags.reader import read_bag_frames
from bbpose_ros.cli import synth
from bbpose_ros.cli.main import main
from bbpose_ros.core.data.bop import BopDataset
from bbpose_ros.core.synth import SyntheticScenes
from bbpose_ros.core.util.errors import InputError

pytestmark = pytest.mark.slow   # renders with OpenGL


@pytest.fixture(autouse=True)
def session_models(monkeypatch, lmo_models):
    """Serve the session's LM-O models instead of parsing all meshes again in every run."""
    def load(dataset_dir, names=None):
        return {name: model for name, model in lmo_models.items() if not names or name in names}

    monkeypatch.setattr(synth, 'load_bop_models', load)


def parse(*argv):
    """Parse a ``synth`` command line with a parser built by ``add_parser``."""
    parser = argparse.ArgumentParser(prog='bbpose')
    synth.add_parser(parser.add_subparsers(dest='command', required=True))
    return parser.parse_args(['synth', *argv])


def test_writes_a_bop_dataset(egl, tmp_path, lmo_root):
    out = tmp_path / 'synth'
    args = parse('--dataset', str(lmo_root), '--out', str(out), '--count', '2', '--seed', '4',
                 '--objects', 'ape,duck,glue', '--previews', '1')
    assert args.func(args) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ['synth']
    assert [p.name for p in (out / 'previews').iterdir()] == ['000000.png']
    assert (out / 'synth_info.json').is_file()
    frames = BopDataset(out, split='train_synth').frames()
    assert [frame.image_id for frame in frames] == [0, 1]
    names = {instance.object_name for frame in frames for instance in frame.instances}
    assert names and names <= {'ape', 'duck', 'glue'}
    for frame in frames:
        assert frame.load_image().shape == (480, 640, 3)
        for instance in frame.instances:
            assert 0.35 <= np.linalg.norm(instance.translation) <= 1.5
            assert np.linalg.det(instance.rotation) == pytest.approx(1.0, abs=1e-6)
            assert 0.0 < instance.visib_fract <= 1.0
            assert np.all(instance.box_uv[2:] > instance.box_uv[:2])
    mask_files = list((out / 'train_synth' / '000000' / 'mask_visib').iterdir())
    assert len(mask_files) == sum(len(frame.instances) for frame in frames)


def test_table_scenes_make_a_dataset_that_eval_scores(egl, tmp_path, lmo_root, capsys):
    out = tmp_path / 'table'
    args = parse('--dataset', str(lmo_root), '--out', str(out), '--count', '2',
                 '--scene-style', 'table', '--objects', 'duck')
    assert args.func(args) == 0
    assert 'wrote 2 table images of duck' in capsys.readouterr().out
    assert json.loads((out / 'synth_info.json').read_text())['scene_style'] == 'table'
    assert sorted(p.name for p in (out / 'models').iterdir()) == sorted(
        p.name for p in (lmo_root / 'models').iterdir())
    frames = BopDataset(out, split='train_synth').frames()
    assert {i.object_name for f in frames for i in f.instances} == {'duck'}
    report = tmp_path / 'report.json'
    assert main(['eval', '--dataset', str(out), '--split', 'train_synth', '--objects', 'duck',
                 '--boxes', 'gt', '--rotation', 'gt', '--no-refine', '--json',
                 str(report)]) == 0
    scored = json.loads(report.read_text())
    assert scored['config']['split'] == 'train_synth'
    assert scored['objects']['duck']['add_s_recall'] > 0.5


def test_a_camera_path_makes_a_camera_rate_bag(egl, tmp_path, lmo_root):
    out = tmp_path / 'path'
    args = parse('--dataset', str(lmo_root), '--out', str(out), '--count', '3',
                 '--scene-style', 'table', '--objects', 'duck,glue', '--camera-path',
                 '--orbit-speed', '30')
    assert args.func(args) == 0
    assert json.loads((out / 'synth_info.json').read_text())['camera_path'] == {
        'rate_hz': 30.0, 'orbit_deg_per_s': 30.0, 'bob_m': 0.02, 'moved': None}
    assert main(['make-bag', '--dataset', str(out), '--split', 'train_synth', '--rate', '30',
                 '--out', str(tmp_path / 'bag'), '--start-stamp', '5']) == 0
    frames = read_bag_frames(tmp_path / 'bag')
    assert np.allclose(np.diff([f.stamp_ns for f in frames]), 1e9 / 30, atol=1)
    assert all(f.ground_truth for f in frames)
    # Each frame carries its exact camera pose: the objects stand still in the world.
    rendered = BopDataset(out, split='train_synth').frames()
    for frame, bag_frame in zip(rendered, frames):
        assert np.allclose(frame.world_from_camera, bag_frame.world_from_camera, atol=1e-9)
    in_world = [{i.object_name: f.world_from_camera[:3, :3] @ i.translation
                 + f.world_from_camera[:3, 3] for i in f.instances} for f in rendered]
    for name in in_world[0]:
        assert np.linalg.norm(in_world[0][name] - in_world[2][name]) < 1e-6
    # One scene: the first frame's objects, seen from a camera that moved.
    assert not np.array_equal(frames[0].image_rgb, frames[2].image_rgb)


def test_a_moved_object_stands_elsewhere_from_the_middle_of_the_path(egl, tmp_path, lmo_root):
    out = tmp_path / 'moved'
    args = parse('--dataset', str(lmo_root), '--out', str(out), '--count', '4',
                 '--scene-style', 'table', '--objects', 'duck,glue', '--camera-path',
                 '--move', 'duck:0.05,0.0', '--previews', '0')
    assert args.func(args) == 0
    rendered = BopDataset(out, split='train_synth').frames()

    def in_world(frame, name):
        instance = next(i for i in frame.instances if i.object_name == name)
        return frame.world_from_camera[:3, :3] @ instance.translation + \
            frame.world_from_camera[:3, 3]
    assert np.allclose(in_world(rendered[2], 'duck') - in_world(rendered[1], 'duck'),
                       [0.05, 0.0, 0.0], atol=1e-6)
    assert np.allclose(in_world(rendered[2], 'glue'), in_world(rendered[1], 'glue'), atol=1e-6)


@pytest.mark.parametrize('argv, message', [
    (['--count', '1', '--camera-path'], '--camera-path needs --scene-style table'),
    (['--count', '1', '--scene-style', 'table', '--move', 'duck:0.1,0'], '--move duck'),
    (['--count', '1', '--scene-style', 'table', '--rate', '15'], '--rate is for --camera-path'),
    (['--count', '0'], '--count'),
    (['--count', '1', '--objects', 'ape,teapot'], 'teapot'),
    (['--count', '1', '--seed', '-3'], '--seed'),
    (['--count', '1', '--inplane-range-deg', '30,-30'], 'inplane_range_deg'),
])
def test_bad_input_is_an_input_error(tmp_path, lmo_root, argv, message):
    args = parse('--dataset', str(lmo_root), '--out', str(tmp_path / 'out'), *argv)
    with pytest.raises(InputError, match=message):
        args.func(args)
    assert list(tmp_path.iterdir()) == []


def test_missing_dataset_and_existing_output(tmp_path):
    args = parse('--dataset', str(tmp_path / 'nowhere'), '--out', str(tmp_path / 'out'),
                 '--count', '1')
    with pytest.raises(InputError, match='dataset folder not found'):
        args.func(args)
    args = parse('--dataset', str(tmp_path), '--out', str(tmp_path), '--count', '1')
    with pytest.raises(InputError, match='already exists'):
        args.func(args)


def test_failure_leaves_no_partial_output(tmp_path, lmo_root, monkeypatch):
    def broken(self, index):
        raise OSError('disk full')

    monkeypatch.setattr(SyntheticScenes, 'sample', broken)
    args = parse('--dataset', str(lmo_root), '--out', str(tmp_path / 'out'), '--count', '2',
                 '--objects', 'ape')
    with pytest.raises(OSError, match='disk full'):
        args.func(args)
    assert list(tmp_path.iterdir()) == []
