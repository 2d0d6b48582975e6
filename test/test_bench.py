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

"""``bbpose bench`` as a user runs it: valid JSON with every key; never a timed assertion."""

import json
import os
import subprocess
import sys

from test_ros_support import REPO_ROOT, use_private_domain, weight_files

from bbpose_ros.core.eval.benchmark import ProcessSample, STAGES, summarize_graph

STATS = {'median_ms', 'p95_ms', 'max_ms'}


def bench(tmp_path, lmo_root, *args):
    """Run ``bbpose bench`` on two LM-O frames; returns (CompletedProcess, report or None)."""
    detector, qnet = weight_files(tmp_path)
    out = tmp_path / 'bench.json'
    result = subprocess.run(
        [sys.executable, '-m', 'bbpose_ros.cli.main', 'bench', '--dataset', lmo_root,
         '--frames', '2', '--warmup', '1', '--threads', '1', '--json', out,
         '--param', f'detector_weights:={detector}', '--param', f'qnet_weights:={qnet}',
         *args],
        capture_output=True, text=True, timeout=300, cwd=REPO_ROOT, env=dict(os.environ))
    return result, json.loads(out.read_text()) if out.is_file() else None


def test_stage_bench_writes_every_key(lmo_root, tmp_path):
    result, report = bench(tmp_path, lmo_root)
    assert result.returncode == 0, result.stderr
    assert 'bbox_equation_per_object' in result.stdout and 'budget' in result.stdout
    assert {'stages', 'total', 'fps', 'peak_rss_mb', 'objects_per_frame'} <= set(report)
    for summary in (report, report['all_objects']):
        assert set(summary['stages']) <= set(STAGES)
        assert {'image_conversion', 'detector', 'messages'} <= set(summary['stages'])
        assert all(set(stats) == STATS for stats in summary['stages'].values())
        assert set(summary['total']) == STATS and summary['fps'] > 0
    assert {'qnet', 'bbox_equation_per_object'} <= set(report['all_objects']['stages'])
    assert report['all_objects']['objects_per_frame'] >= 6        # LM-O: 6 to 8 per frame
    assert report['inference_threads'] == 1 and report['frames'] == 2
    assert report['inference_backend'] == 'onnxruntime'
    assert report['peak_rss_mb'] > 0
    assert all({'value', 'limit', 'met'} == set(b) for b in report['budgets'].values())


def test_graph_bench_answers_and_writes_every_key(lmo_root, tmp_path):
    use_private_domain(offset=5)
    result, report = bench(tmp_path, lmo_root, '--graph', '--rate', '4', '--duration', '2')
    assert result.returncode == 0, result.stderr
    assert 'publish -> markers' in result.stdout
    for key in ('latency', 'answer_latency'):
        assert set(report[key]) == STATS
    frames = report['frames']
    assert frames['published'] == 8 and frames['answered'] >= 1
    assert frames['answered'] + frames['dropped'] == frames['published']
    assert report['answer_latency']['median_ms'] > 0
    node = report['node']
    assert node['rss_start_mb'] > 0 and node['rss_end_mb'] > 0 and node['cpu_percent'] >= 0
    assert len(node['rss_trace_mb']) == 2                 # frames 0 and 4 of 8 at 4 Hz
    assert node['rss_settled_mb'] is None                # a 2 s run never settles
    assert isinstance(node['counts'], dict)


def test_rss_after_settling_tells_a_step_from_a_climb():
    latencies = [{'end_to_end': 10.0, 'answer': 11.0}] * 30
    start, end = ProcessSample(0.0, 0.0, 400.0), ProcessSample(30.0, 15.0, 442.0)
    step = [(0.0, 400.0), (5.0, 440.0), (10.5, 441.0), (20.0, 441.5)]
    climb = [(0.0, 400.0), (5.0, 407.0), (10.5, 414.0), (20.0, 428.0)]
    for trace, after in ((step, 100 * 1 / 441), (climb, 100 * 28 / 414)):
        node = summarize_graph(latencies, 30, start, end, {}, trace)['node']
        assert abs(node['rss_growth_percent'] - 10.5) < 1e-9
        assert abs(node['rss_growth_after_settle_percent'] - after) < 1e-9
        assert node['cpu_percent'] == 50.0
