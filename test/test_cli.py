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

"""The ``bbpose`` command as a user runs it: real output, clear errors, no half files."""

import json
import os
from pathlib import Path
import subprocess
import sys

import pytest

from bbpose_ros.cli.main import main
from bbpose_ros.core.data.bop import BopDataset
from bbpose_ros.core.eval.instance_scores import POSE_KEYS
from bbpose_ros.core.eval.paired import instances_path

pytestmark = pytest.mark.slow   # runs the bbpose CLI as a process


def bbpose(*args, cwd=None):
    """Run ``bbpose`` in a fresh interpreter; returns the CompletedProcess."""
    return subprocess.run([sys.executable, '-m', 'bbpose_ros.cli.main', *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=300,
                          env={**os.environ, 'PYTHONPATH': str(Path(__file__).parents[1])})


def bbpose_here(capsys, *args):
    """
    Run ``bbpose`` in this interpreter, as ``python -m bbpose_ros.cli.main`` runs it.

    For refusals of bad input, which happen before any work: no interpreter and torch to
    start for each. The exit code is main's return value or the SystemExit's code (argparse);
    a real process's exit code 2 is checked by the other tests of this file.
    """
    try:
        code = main([str(a) for a in args])
    except SystemExit as exit_:
        code = exit_.code
    out = capsys.readouterr()
    return subprocess.CompletedProcess(['bbpose', *args], code, out.out, out.err)


def test_eval_refines_perturbed_ground_truth_sweep(lmo_root, tmp_path):
    out = tmp_path / 'report.json'
    result = bbpose('eval', '--dataset', lmo_root, '--boxes', 'gt', '--rotation', 'gt',
                    '--perturb-gt', '10,20', '--perturb-gt', '30,20', '--objects',
                    'duck,holepuncher', '--max-frames', '12', '--json', out,
                    '--plots', tmp_path / 'plots')
    assert result.returncode == 0, result.stderr
    report = json.loads(out.read_text())
    sweep = {level['deg']: level['mean'] for level in report['sweep']}
    assert sorted(sweep) == [10.0, 30.0] and report['mean'] == sweep[10.0]
    # Unrefined, a start 10 deg off never passes 5 cm / 5 deg; refined, some do, and a
    # start 30 deg off ends further from the truth than one 10 deg off.
    assert sweep[10.0]['cm5deg5'] > 0.05
    assert sweep[10.0]['re_median_deg'] < sweep[30.0]['re_median_deg']
    assert 'refinement' in report['timing_ms']
    assert (tmp_path / 'plots' / 'refinement_basin.png').stat().st_size > 1000
    assert 'start 30 deg / 20 mm' in result.stdout
    # What a minimum confidence keeps: everything at 0, less and less above; at 0 the share
    # passing 5 cm / 5 deg is the pooled one of the per-object figures.
    confidence = report['confidence']
    kept = [row['kept'] for row in confidence]
    assert kept[0] == 1.0 and kept == sorted(kept, reverse=True) and kept[-1] < 1.0
    objects = report['objects'].values()
    pooled = sum(o['cm5deg5'] * o['n'] for o in objects) / sum(o['detected'] for o in objects)
    assert confidence[0]['cm5deg5_precision'] == pytest.approx(pooled)
    assert (tmp_path / 'plots' / 'confidence.png').stat().st_size > 1000
    assert 'minimum confidence' in result.stdout
    bad = bbpose('eval', '--dataset', lmo_root, '--boxes', 'detector', '--perturb-gt', '5,5')
    assert bad.returncode == 2 and '--perturb-gt needs --boxes gt --rotation gt' in bad.stderr


def test_eval_perturbs_the_truth_along_the_viewing_ray(lmo_root, tmp_path):
    out = tmp_path / 'report.json'
    result = bbpose('eval', '--dataset', lmo_root, '--boxes', 'gt', '--rotation', 'gt',
                    '--perturb-gt', '0,60', '--perturb-direction', 'ray', '--no-refine',
                    '--objects', 'duck,can', '--max-frames', '6', '--json', out)
    assert result.returncode == 0, result.stderr
    report = json.loads(out.read_text())
    assert report['config']['perturb_direction'] == 'ray'
    # Unrefined, the start is scored: the exact rotation, the translation 60 mm off along
    # the ray, so the box it projects to stays centred where the truth's is.
    records = json.loads(instances_path(out).read_text())
    assert records and all(r['te_mm'] == pytest.approx(60.0) and r['re_deg'] < 1e-3
                           for r in records)
    assert report['mean']['proj5px'] > 0.5


def test_eval_with_ground_truth_boxes_and_rotations(lmo_root, tmp_path):
    out = tmp_path / 'report.json'
    result = bbpose('eval', '--dataset', lmo_root, '--boxes', 'gt', '--rotation', 'gt',
                    '--no-refine', '--objects', 'ape,driller', '--max-frames', '10',
                    '--json', out, '--plots', tmp_path / 'plots')
    assert result.returncode == 0, result.stderr
    assert 'driller' in result.stdout and 'mean' in result.stdout
    for chart in ('recall_curves.png', 'objects.png', 'visibility.png'):
        assert (tmp_path / 'plots' / chart).stat().st_size > 1000
    report = json.loads(out.read_text())
    assert sorted(report['objects']) == ['ape', 'driller']
    for values in list(report['objects'].values()) + [report['mean']]:
        assert set(POSE_KEYS) <= set(values)
    assert report['mean']['te_median_mm'] < 10.0
    assert report['objects']['driller']['n'] == 10
    assert {'translation', 'total'} <= set(report['timing_ms'])


def test_eval_with_the_detector_reports_detection_metrics(lmo_root, tmp_path):
    frames = 5    # the 5th LM-O frame has an ape with visib_fract 0.06: not counted
    out = tmp_path / 'report.json'
    result = bbpose('eval', '--dataset', lmo_root, '--boxes', 'detector', '--max-frames',
                    frames, '--json', out)
    assert result.returncode == 0, result.stderr
    assert 'recall50' in result.stdout and 'AP50' in result.stdout
    report = json.loads(out.read_text())
    assert set(POSE_KEYS) <= set(report['mean'])       # the pose report's own mean is kept
    detection = report['detection']
    names = sorted(BopDataset(lmo_root).load_models())
    assert len(names) == 8 and sorted(set(detection) - {'mean'}) == names
    counted = dict.fromkeys(names, 0)
    strict = dict.fromkeys(names, 0)
    for frame in BopDataset(lmo_root).frames()[:frames]:
        for instance in frame.instances:
            counted[instance.object_name] += instance.visib_fract >= 0.1
            strict[instance.object_name] += instance.visib_fract >= 0.3
    assert counted['ape'] < frames    # the visibility cut is exercised
    for name in names:
        values = detection[name]
        assert values['n'] == counted[name] and values['n_visib30'] == strict[name]
        for key in ('recall_iou50', 'ap50', 'recall_iou50_visib30'):
            assert 0.0 <= values[key] <= 1.0, (name, key, values[key])
    for key in ('recall_iou50', 'ap50', 'recall_iou50_visib30'):
        assert 0.0 <= detection['mean'][key] <= 1.0


def test_make_bag_writes_a_bag(lmo_root, tmp_path):
    result = bbpose('make-bag', '--dataset', lmo_root, '--out', tmp_path / 'bag',
                    '--max-frames', '2', '--start-stamp', '10')
    assert result.returncode == 0, result.stderr
    assert (tmp_path / 'bag' / 'metadata.yaml').is_file()


def test_bad_input_exits_nonzero_naming_the_problem(lmo_root, tmp_path, capsys):
    def bbpose(*args):
        return bbpose_here(capsys, *args)

    out = tmp_path / 'report.json'
    missing = bbpose('eval', '--dataset', tmp_path / 'nope', '--boxes', 'gt', '--rotation',
                     'gt', '--json', out)
    assert missing.returncode == 2
    assert 'dataset folder not found' in missing.stderr and 'nope' in missing.stderr
    unknown = bbpose('eval', '--dataset', lmo_root, '--boxes', 'gt', '--rotation', 'gt',
                     '--objects', 'ape,banana', '--json', out)
    assert unknown.returncode == 2 and 'banana' in unknown.stderr
    weights = bbpose('eval', '--dataset', lmo_root, '--boxes', 'gt', '--max-frames', '1',
                     '--qnet-weights', tmp_path / 'mine.pt', '--json', out)
    assert weights.returncode == 2 and 'mine.pt' in weights.stderr
    weight = bbpose('eval', '--dataset', lmo_root, '--boxes', 'gt', '--max-frames', '1',
                    '--box-consistency-weight', '-1', '--json', out)
    assert weight.returncode == 2 and '--box-consistency-weight: -1.0 is out of range' in \
        weight.stderr
    bag = bbpose('make-bag', '--dataset', tmp_path / 'nope', '--out', tmp_path / 'bag')
    assert bag.returncode == 2 and 'nope' in bag.stderr
    video = bbpose('replay-eval', '--bag', tmp_path / 'bag', '--json', out, '--video',
                   tmp_path / 'replay.avi')
    assert video.returncode == 2 and 'replay.avi' in video.stderr and '.mp4' in video.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_eval_writes_instance_records_that_compare_pairs(lmo_root, tmp_path):
    out = tmp_path / 'r.json'
    result = bbpose('eval', '--dataset', lmo_root, '--boxes', 'gt', '--rotation', 'gt',
                    '--no-refine', '--max-frames', '2', '--json', out)
    assert result.returncode == 0, result.stderr
    report = json.loads(out.read_text())
    records = json.loads((tmp_path / 'r.instances.json').read_text())
    assert len(records) == sum(o['n'] for o in report['objects'].values())
    assert {'key', 'object', 'found', 'add_s', 'cm5deg5', 'te_mm'} <= set(records[0])
    same = bbpose('compare', out, tmp_path / 'r.instances.json')
    assert same.returncode == 0, same.stderr
    assert '+0.000   [+0.000, +0.000]' in same.stdout
    missing = bbpose('compare', out, tmp_path / 'nope.json')
    assert missing.returncode == 2 and 'nope.instances.json' in missing.stderr
