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

"""bbpose_node's start and stop: bad configurations refused clearly, SIGTERM honoured."""

import signal
import subprocess
import sys
import time

import pytest
from test_ros_support import NodeLog, REPO_ROOT, use_private_domain, weight_files
from test_ros_support import write_params


@pytest.fixture(scope='module')
def weights(tmp_path_factory):
    use_private_domain(offset=1)
    return weight_files(tmp_path_factory.mktemp('weights'))


def start(params, *overrides):
    """Start the node with a parameters file and ``-p`` overrides; returns the Popen."""
    command = [sys.executable, '-m', 'bbpose_ros.ros.node', '--ros-args',
               '--params-file', str(params)]
    for override in overrides:
        command += ['-p', override]
    return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, cwd=REPO_ROOT)


@pytest.mark.parametrize('values, overrides, expected', [
    ({'score_threshold': 1}, (), "parameter 'score_threshold'"),             # int for float
    ({}, ('max_instances:=0',), 'max_instances out of range'),
    ({'objects': ['ape', 'teapot']}, (), 'unknown object name(s) teapot'),
    ({'qnet_weights': '/nonexistent/qnet.pt'}, (), 'qnet_weights: weights file not found'),
    ({'dataset_dir': '/nonexistent'}, (), 'dataset_dir: /nonexistent has no models/'),
    ({'inference_backend': 'tensorrt'}, (), 'inference_backend: "tensorrt" is not one of'),
    ({'device': 'cuda'}, (), 'onnxruntime runs on the CPU only'),
])
def test_bad_configuration_is_refused_clearly(lmo_root, weights, tmp_path, values, overrides,
                                              expected):
    params = write_params(tmp_path / 'params.yaml', lmo_root, weights, **values)
    process = start(params, *overrides)
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == 1
    assert 'cannot start' in stderr and expected in stderr, stderr
    assert 'Traceback' not in stderr


def test_sigterm_stops_the_node_within_two_seconds(lmo_root, weights, tmp_path):
    log = NodeLog(tmp_path / 'node.log')
    params = write_params(tmp_path / 'params.yaml', lmo_root, weights, objects=['ape'])
    process = subprocess.Popen([sys.executable, '-m', 'bbpose_ros.ros.node', '--ros-args',
                                '--params-file', str(params)], stderr=log.file)
    assert log.wait_for('serving ape'), log.path.read_text()
    process.send_signal(signal.SIGTERM)
    start_s = time.monotonic()
    code = process.wait(10.0)
    assert time.monotonic() - start_s < 2.0
    assert code == 0
