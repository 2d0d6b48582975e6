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

"""Objects known by the names a dataset gives them (models/models_names.json)."""

import json
import os
import shutil

import pytest

from bbpose_ros.cli.main import main
from bbpose_ros.core.data.bop import BopDataset
from bbpose_ros.core.data.models import bop_object_ids, LMO_OBJECTS, load_bop_models, \
    NAMES_FILE, object_names
from bbpose_ros.core.util.errors import InputError

LMO_IDS = (1, 5, 6, 8, 9, 10, 11, 12)


def models_folder(root, ids=LMO_IDS, names=None):
    """Write ``root/models/`` with a models_info.json of ``ids`` and a names table if given."""
    (root / 'models').mkdir(parents=True)
    info = {str(obj_id): {'diameter': 100.0} for obj_id in ids}
    (root / 'models' / 'models_info.json').write_text(json.dumps(info))
    if names is not None:
        (root / 'models' / NAMES_FILE).write_text(json.dumps(names))
    return root


def named_copy(lmo_root, tmp_path, names):
    """Link LM-O into ``tmp_path`` (JSON files copied) with ``names`` as its names table."""
    root = tmp_path / 'lmo'
    shutil.copytree(lmo_root, root, symlinks=True,
                    copy_function=lambda src, dst: os.symlink(src, dst))
    (root / 'models' / NAMES_FILE).write_text(json.dumps(names))
    return root


def toy_names():
    """LM-O's names with object 1 (the ape's id) called 'toy'."""
    return {str(obj_id): 'toy' if obj_id == 1 else name
            for obj_id, name in zip(LMO_IDS, LMO_OBJECTS)}


def test_without_a_table_the_names_are_linemods(tmp_path):
    root = models_folder(tmp_path, ids=(1, 9, 16))
    assert object_names(root) == {1: 'ape', 9: 'duck', 16: 'obj_000016'}
    assert object_names(tmp_path / 'no_models') == {}


def test_the_table_names_the_objects(tmp_path):
    root = models_folder(tmp_path, ids=(1, 16), names={'16': 'toy', '1': 'gear_2'})
    assert object_names(root) == {1: 'gear_2', 16: 'toy'}
    assert bop_object_ids(root) == {'gear_2': 1, 'toy': 16}


@pytest.mark.parametrize('names, message', [
    ({'1': 'toy'}, r'object id\(s\) 5 of models_info.json without a name \(ids of '),
    ({'1': 'toy', '5': 'can', '7': 'cup'}, r'object id\(s\) 7 not in models_info.json'),
    ({'1': 'my toy', '5': 'can'}, r"invalid object name\(s\) 'my toy'"),
    ({'1': 'toy', '5': 'toy'}, r'name\(s\) toy given to several ids'),
    (['toy'], 'expected a JSON object'),
])
def test_a_bad_table_is_named(tmp_path, names, message):
    root = models_folder(tmp_path, ids=(1, 5), names=names)
    with pytest.raises(InputError, match=f'{NAMES_FILE}: {message}'):
        object_names(root)


def test_a_named_dataset_loads_toy_and_refuses_ape(lmo_root, tmp_path):
    root = named_copy(lmo_root, tmp_path, toy_names())
    models = load_bop_models(root, ['toy', 'duck'])
    assert list(models) == ['toy', 'duck'] and models['toy'].obj_id == 1
    assert models['toy'].name == 'toy'
    frames = BopDataset(root).frames()
    assert 'toy' in {i.object_name for f in frames for i in f.instances if i.obj_id == 1}
    with pytest.raises(InputError, match=r'unknown object name\(s\) ape in .*models_names\.json'
                                         r'; known: toy, can, cat'):
        load_bop_models(root, ['ape'])


def test_an_unknown_name_says_where_the_names_come_from(lmo_root):
    with pytest.raises(InputError, match=r"unknown object name\(s\) toy in .*models \(LineMod's "
                                         r'names by BOP id: no models_names.json\); known: ape'):
        load_bop_models(lmo_root, ['toy'])


def test_eval_accepts_objects_toy(lmo_root, tmp_path, capsys):
    root = named_copy(lmo_root, tmp_path, toy_names())
    report = tmp_path / 'report.json'
    assert main(['eval', '--dataset', str(root), '--objects', 'toy', '--boxes', 'gt',
                 '--rotation', 'gt', '--max-frames', '2', '--no-refine', '--json',
                 str(report)]) == 0
    assert list(json.loads(report.read_text())['objects']) == ['toy']
    assert main(['eval', '--dataset', str(root), '--objects', 'ape']) == 2
    assert 'unknown object name(s) ape' in capsys.readouterr().err


def test_eval_names_the_splits_it_finds(lmo_root, tmp_path, capsys):
    assert main(['eval', '--dataset', str(lmo_root), '--split', 'train_synth']) == 2
    assert f'split folder not found: {lmo_root / "train_synth"} (splits in {lmo_root}: test)' \
        in capsys.readouterr().err
