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

import pytest
from test_ros_support import REPO_ROOT, use_private_domain, weight_files

from bbpose_ros.core.eval.benchmark import ProcessSample, rss_settle_s, STAGES
from bbpose_ros.core.eval.benchmark import summarize_graph

pytestmark = pytest.mark.slow   # runs the bbpose CLI and bbpose_node as processes

STATS = {'median_ms', 'p95_ms', 'max_ms'}


def bench(tmp_path, lmo_root, *args):
    """Run ``bbpose bench`` on two LM-O frames; returns (CompletedProcess, report or None)."""
    detector, qnet = weight_files(tmp_path)
    out = tmp_path / 'bench.json'
    result = subprocess.run(
        [sys.executable, '-m', 'bbpose_ros.cli.main', 'bench', '--dataset', lmo_root,
         '--frames', '2', '--warmup', '1', '--inference-threads', '1', '--json', out,
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
    # The decode of a JPEG of the frame (image_transport compressed), apart from the total.
    assert set(report['stages']['image_decode']) == STATS and 'image_decode' in result.stdout
    assert report['image_decode'] == {'codec': 'jpeg', 'jpeg_quality': 95}
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
    assert node['rss_settled_at_s'] == 10.0
    assert [m['minute'] for m in report['per_minute']] == [1]
    assert report['per_minute'][0]['published'] == 8
    assert report['latency_p95_drift_percent'] is None   # no full minute
    assert isinstance(node['counts'], dict)
    # The stop is timed and its exit code kept; test_node* assert a clean stop's code.
    assert node['stop_s'] > 0 and isinstance(node['exit_code'], int)
    assert 'node stop (SIGINT -> exit)' in result.stdout


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


def test_a_soak_reports_per_minute_and_its_drift():
    rate_hz, minutes = 2.0, 3
    latencies = [{'end_to_end': 10.0, 'answer': 10.0 + minute}      # p95 10, 11, 12 ms
                 for minute in range(minutes) for _ in range(int(60 * rate_hz))]
    latencies[5] = {}                                                 # one frame dropped
    trace = [(float(s), 400.0 + s / 60) for s in range(0, 180, 1)]   # +1 MB a minute
    start, end = ProcessSample(0.0, 0.0, 400.0), ProcessSample(180.0, 90.0, 403.0)
    report = summarize_graph(latencies, len(latencies), start, end, {}, trace,
                             rate_hz=rate_hz, settle_s=rss_settle_s(180.0))
    per_minute = report['per_minute']
    assert [(m['minute'], m['published'], m['answered']) for m in per_minute] == [
        (1, 120, 119), (2, 120, 120), (3, 120, 120)]
    assert [m['answer_latency_p95_ms'] for m in per_minute] == [10.0, 11.0, 12.0]
    assert abs(per_minute[1]['rss_mb'] - (400.0 + 119 / 60)) < 1e-9   # the minute's last
    assert abs(report['latency_p95_drift_percent'] - 20.0) < 1e-9
    node = report['node']
    assert node['rss_settled_at_s'] == 60.0 and node['rss_settled_mb'] == 401.0
    assert abs(node['rss_growth_after_settle_percent'] - 100 * 2 / 401) < 1e-9
    budgets = report['budgets']
    assert budgets['rss_growth_after_settle_percent']['met']
    assert not budgets['latency_p95_drift_percent']['met']
    assert not budgets['frames_dropped']['met']
