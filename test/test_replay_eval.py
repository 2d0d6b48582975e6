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

"""``bbpose replay-eval``: every frame answered, scored like ``bbpose eval``, files written."""

import json
import math
import subprocess
import sys
import time

import cv2
import numpy as np
import pytest
from rclpy.serialization import deserialize_message
from rosbags.rosbag2 import Reader
from test_ros_support import REPO_ROOT, use_private_domain, weight_files, write_params
from vision_msgs.msg import Detection3DArray

from bbpose_ros.bags.writer import write_bop_bag
from bbpose_ros.cli.replay_eval import per_frame_in_lockstep, unscored_poses
from bbpose_ros.core.eval.evaluation import evaluate
from bbpose_ros.core.eval.instance_scores import POSE_KEYS
from bbpose_ros.core.eval.paired import read_instances
from bbpose_ros.core.eval.recorded_poses import Recording
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.pipeline.loader import load_pipeline, WeightFiles
from bbpose_ros.core.util.errors import InputError

pytestmark = pytest.mark.slow   # runs bbpose replay-eval and bbpose_node as processes

FRAMES = 3
PACED_HZ = 2.0     # the paced bag's rate


def test_replay_eval_answers_every_frame_and_scores_like_eval(lmo, lmo_root, lmo_models,
                                                              tmp_path):
    use_private_domain(offset=3)
    weights = weight_files(tmp_path)
    frames = lmo.frames()[:FRAMES]
    write_bop_bag(frames, tmp_path / 'bag', start_stamp_ns=10 ** 9, progress=False)
    params = write_params(tmp_path / 'params.yaml', lmo_root, weights)
    out = tmp_path / 'out' / 'report.json'
    result = subprocess.run(
        [sys.executable, '-m', 'bbpose_ros.cli.main', 'replay-eval', '--bag', tmp_path / 'bag',
         '--json', out, '--plots', tmp_path / 'plots', '--params', params,
         '--compare-tracking', '--video', tmp_path / 'replay.mp4'],
        capture_output=True, text=True, timeout=300, cwd=REPO_ROOT)
    assert result.returncode == 0, result.stderr
    assert 'mean' in result.stdout and f'{FRAMES} sent, {FRAMES} answered' in result.stdout

    report = json.loads(out.read_text())
    assert report['frames'] == {'sent': FRAMES, 'answered': FRAMES}
    assert set(report['objects']) == set(lmo_models)
    for values in list(report['objects'].values()) + [report['mean']]:
        assert set(POSE_KEYS) <= set(values)
    assert {'end_to_end', 'detector', 'rotation', 'total'} <= set(report['timing_ms'])
    assert report['timing_ms']['end_to_end']['median'] > 0

    # The second replay, with tracking on, answered every frame too.
    assert report['tracking']['off']['mean'] == report['mean']
    assert report['tracking']['on']['frames'] == {'sent': FRAMES, 'answered': FRAMES}
    assert 'tracking on: ADD(-S)' in result.stdout

    offline = evaluate(frames, load_pipeline(lmo_models, PipelineOptions(score_threshold=0.0),
                                             WeightFiles(*weights)),
                       boxes='detector', rotation='estimator', progress=False)
    for name, values in offline['objects'].items():
        for key in ('n', 'detected', 'add_s_recall', 'cm5deg5', 'proj5px'):
            mine, theirs = report['objects'][name][key], values[key]
            assert mine == theirs or (math.isnan(theirs) and mine is None), (name, key)

    # One record per scored instance beside the report, for `bbpose compare`.
    records = read_instances(out)
    assert len(records) == sum(values['n'] for values in report['objects'].values())
    for name, values in report['objects'].items():
        passed = [r['add_s'] for r in records.values() if r['object'] == name]
        assert len(passed) == values['n']
        assert not passed or sum(passed) / len(passed) == pytest.approx(values['add_s_recall'])

    with Reader(out.parent / 'report_results_bag') as bag:
        recorded = {c.topic: c.msgtype for c in bag.connections}
        poses = sum(1 for c, _, _ in bag.messages() if c.topic.endswith('/pose'))
        arrays = [deserialize_message(bytes(raw), Detection3DArray)
                  for c, _, raw in bag.messages() if c.topic == '/bbpose_node/detections']
    assert {'/bbpose_node/markers', '/diagnostics', '/tf'} <= set(recorded)
    assert recorded['/bbpose_node/detections'] == 'vision_msgs/msg/Detection3DArray'
    assert poses > 0 and sum(len(a.detections) for a in arrays) == poses
    # ~/detections carries the same poses as the PoseStamped topics, so it scores the same.
    assert report['detections'] == {'mean': report['mean'], 'arrays': FRAMES,
                                    'detections': poses, 'tf_transforms': poses}

    video = cv2.VideoCapture(str(tmp_path / 'replay.mp4'))
    height, width = frames[0].camera.height, frames[0].camera.width
    assert [video.get(cv2.CAP_PROP_FRAME_COUNT), video.get(cv2.CAP_PROP_FRAME_HEIGHT),
            video.get(cv2.CAP_PROP_FRAME_WIDTH)] == [FRAMES, height, 2 * width]
    video.release()
    assert f'video of {FRAMES} frames' in result.stdout
    assert {p.name for p in (tmp_path / 'plots').iterdir()} >= {
        'recall_curves.png', 'objects.png', 'overlay_0000.png'}


def test_a_paced_replay_streams_at_the_bags_rate(lmo, lmo_root, tmp_path):
    use_private_domain(offset=4)
    weights = weight_files(tmp_path)
    # PACED_HZ: slower than the node, which answers every frame as it comes, also with the
    # other test worker's load beside it.
    write_bop_bag(lmo.frames()[:FRAMES], tmp_path / 'bag', rate_hz=PACED_HZ,
                  start_stamp_ns=10 ** 9, progress=False)
    params = write_params(tmp_path / 'params.yaml', lmo_root, weights)
    out = tmp_path / 'paced.json'
    started = time.monotonic()
    result = subprocess.run(
        [sys.executable, '-m', 'bbpose_ros.cli.main', 'replay-eval', '--bag', tmp_path / 'bag',
         '--json', out, '--params', params, '--paced'],
        capture_output=True, text=True, timeout=300, cwd=REPO_ROOT)
    assert result.returncode == 0, result.stderr
    assert time.monotonic() - started >= (FRAMES - 1) / PACED_HZ
    report = json.loads(out.read_text())
    assert report['config']['paced'] is True
    assert report['frames'] == {'sent': FRAMES, 'answered': FRAMES}
    assert len(read_instances(out)) == sum(v['n'] for v in report['objects'].values())


def test_lockstep_replays_run_the_node_per_frame():
    assert per_frame_in_lockstep(['tracking:=true'], {'tracking_stream': True}) == [
        'tracking:=true', 'tracking_stream:=false']
    assert per_frame_in_lockstep([], {'tracking_stream': False}) == ['tracking_stream:=false']
    with pytest.raises(InputError, match='needs --paced'):
        per_frame_in_lockstep(['tracking_stream:=true'], {'tracking_stream': True})


def test_objects_without_ground_truth_report_what_was_published():
    pose = (np.eye(3), np.array([0.0, 0.0, 1.0]))
    recording = Recording(poses={1: [('toy', *pose), ('duck', *pose)], 2: [('toy', *pose)],
                                 3: []})
    objects = {'toy': {'n': 0}, 'duck': {'n': 2}, 'part': {'n': 0}}
    assert unscored_poses(recording, objects) == {'toy': 2, 'part': 0}
