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

"""Instance records of an evaluation, and two runs compared instance by instance."""

import json

import numpy as np
import pytest

from bbpose_ros.core.eval.evaluation import score_frames
from bbpose_ros.core.eval.paired import compare, format_comparison, instances_path
from bbpose_ros.core.eval.paired import (compare_objects, format_objects, read_instances,
                                         read_runs)
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.pipeline.pose_pipeline import PosePipeline
from bbpose_ros.core.util.errors import InputError

FRAMES = 4


def records(frames, models, perturb=None):
    """{key: record} of the unrefined ground truth, perturbed (deg, m) or exact."""
    pipeline = PosePipeline(models, PipelineOptions(refine=False))
    scores, _ = score_frames(frames[:FRAMES], pipeline, boxes='gt', rotation='gt',
                             progress=False, perturb=perturb, seed=3)
    return {f'{s.object_name}@{s.key}': s.record() for v in scores.values() for s in v}


def test_a_turned_start_is_worse_by_its_turn_and_the_interval_says_so(lmo_frames, lmo_models):
    exact, turned = records(lmo_frames, lmo_models), records(lmo_frames, lmo_models,
                                                             (10.0, 0.02))
    assert len(exact) == len(turned) > 10
    assert len({key.split('@')[1] for key in exact}) == len(exact)    # one key an instance
    same = compare(exact, exact)
    assert all(f['diff'] == f['low'] == f['high'] == 0.0 for f in same.values())
    figures = compare(exact, turned)
    # Every instance is found in both; none turned 10 deg passes 5 cm / 5 deg, all exact do.
    assert figures['found']['diff'] == 0.0 and figures['found']['n'] == len(exact)
    assert figures['cm5deg5']['a'] == 1.0 and figures['cm5deg5']['b'] == 0.0
    assert figures['cm5deg5']['high'] == -1.0
    # Moved 20 mm from the truth (the exact run's equation is a few mm off): the median
    # translation error grows by nearly that much.
    te = figures['te_mm']
    assert 10.0 < te['low'] <= te['diff'] <= te['high'] < 25.0
    assert np.isclose(te['b'], 20.0, atol=1.0)
    table = format_comparison(figures, ('exact', 'turned'))
    assert 'cm5deg5' in table and '-1.000' in table


def test_runs_without_shared_instances_or_records_are_refused(tmp_path):
    with pytest.raises(InputError, match='share no instance'):
        compare({'ape@1/1/0': {}}, {'cat@1/1/1': {}})
    with pytest.raises(InputError, match='no instance records at .*r.instances.json'):
        read_instances(tmp_path / 'r.json')
    instances_path(tmp_path / 'r.json').write_text(json.dumps({'not': 'records'}))
    with pytest.raises(InputError, match='not a list of instance records'):
        read_instances(tmp_path / 'r.json')


def test_folds_join_into_one_run_and_objects_compare_alone(lmo_frames, lmo_models, tmp_path):
    exact, turned = records(lmo_frames, lmo_models), records(lmo_frames, lmo_models,
                                                             (10.0, 0.02))
    keys = sorted(exact)
    halves = [{k: exact[k] for k in keys[:5]}, {k: exact[k] for k in keys[5:]}]
    paths = []
    for k, half in enumerate(halves):
        paths.append(tmp_path / f'fold{k}.json')
        instances_path(paths[-1]).write_text(json.dumps(list(half.values())))
    assert read_runs(paths) == exact
    with pytest.raises(InputError, match='disjoint frames'):
        read_runs([paths[0], paths[0]])
    figures = compare_objects(exact, turned)
    assert sorted(figures) == sorted({r['object'] for r in exact.values()})
    for name, rows in figures.items():
        assert rows['found']['n'] == sum(r['object'] == name for r in exact.values())
        assert rows['cm5deg5']['diff'] == -1.0
    assert 'cm5deg5 B - A' in format_objects(figures, ('found', 'cm5deg5'))
