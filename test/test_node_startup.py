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

import pytest
from test_ros_support import NodeLog, REPO_ROOT, TIMEOUT_S, use_private_domain, weight_files
from test_ros_support import write_params

pytestmark = pytest.mark.slow   # starts bbpose_node as a process


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


# One process tries every configuration in turn (``main`` as the console script runs it),
# each between markers on stderr: a start costs seconds, a configuration does not.
TRY_EACH = """
import sys
from bbpose_ros.ros.node import main
for index, args in enumerate(sys.argv[1:]):
    print(f'=== {index} begin', file=sys.stderr, flush=True)
    code = main(args.split('\\t'))
    print(f'=== {index} exit {code}', file=sys.stderr, flush=True)
"""

BAD_CONFIGURATIONS = [
    ({'score_threshold': 1}, (), "parameter 'score_threshold'"),             # int for float
    ({}, ('max_instances:=0',), 'max_instances out of range'),
    ({'objects': ['ape', 'teapot']}, (), 'unknown object name(s) teapot'),
    ({'qnet_weights': '/nonexistent/qnet.pt'}, (), 'qnet_weights: weights file not found'),
    ({'dataset_dir': '/nonexistent'}, (), 'dataset_dir: /nonexistent has no models/'),
    ({'inference_backend': 'tensorrt'}, (), 'inference_backend: "tensorrt" is not one of'),
    ({'device': 'cuda'}, (), 'onnxruntime runs on the CPU only'),
]


def test_bad_configurations_are_refused_clearly(lmo_root, weights, tmp_path):
    runs = []
    for index, (values, overrides, _) in enumerate(BAD_CONFIGURATIONS):
        params = write_params(tmp_path / f'params{index}.yaml', lmo_root, weights, **values)
        args = ['--ros-args', '--params-file', str(params)]
        for override in overrides:
            args += ['-p', override]
        runs.append('\t'.join(args))
    process = subprocess.run([sys.executable, '-c', TRY_EACH, *runs], capture_output=True,
                             text=True, cwd=REPO_ROOT, timeout=600)
    assert process.returncode == 0, process.stderr
    for index, (_, _, expected) in enumerate(BAD_CONFIGURATIONS):
        section = process.stderr.split(f'=== {index} begin')[1].split(f'=== {index} exit')
        assert len(section) == 2, process.stderr
        log, code = section[0], section[1].split()[0]
        assert code == '1', (expected, log)
        assert 'cannot start' in log and expected in log, log
        assert 'Traceback' not in log


def test_sigterm_stops_the_node_cleanly(lmo_root, weights, tmp_path):
    log = NodeLog(tmp_path / 'node.log')
    params = write_params(tmp_path / 'params.yaml', lmo_root, weights, objects=['ape'])
    process = subprocess.Popen([sys.executable, '-m', 'bbpose_ros.ros.node', '--ros-args',
                                '--params-file', str(params)], stderr=log.file)
    assert log.wait_for('serving ape'), log.path.read_text()
    process.send_signal(signal.SIGTERM)
    # How long a stop takes is measured by ``bbpose bench --graph`` (node.stop_s).
    assert process.wait(TIMEOUT_S) == 0
    assert 'Traceback' not in log.path.read_text()
