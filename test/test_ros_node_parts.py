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

"""
The node's parts without a graph: ids, covariances, conditions, rebuilds, refusals.

The last tests hold a BBPoseNode in this process, unconfigured (nothing loaded) and never
spun: its service callbacks are called as the executor would.
"""

import dataclasses
import json
import threading
import time

from diagnostic_msgs.msg import DiagnosticStatus
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
import numpy as np
import pytest
from rcl_interfaces.srv import SetParameters
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter
from std_msgs.msg import Header
from visualization_msgs.msg import Marker

from bbpose_ros.core.geometry.rotations import quat_wxyz_to_matrix
from bbpose_ros.core.pipeline.poses import Detection, PoseEstimate
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.ros import conversions
from bbpose_ros.ros import node as node_module
from bbpose_ros.ros.detections import DetectionsBuilder, load_pose_spread, ObjectSpread
from bbpose_ros.ros.detections import POSE_SPREAD_FILE, resolve_prefix, transforms
from bbpose_ros.ros.diagnostics import counts_from_status, incompatible_qos_text, InputWatch
from bbpose_ros.ros.diagnostics import NodeStats
from bbpose_ros.ros.rebuild import PipelineRebuilder


def _poses(names, scores):
    rotation = quat_wxyz_to_matrix([0.9, 0.1, -0.3, 0.2])
    return [PoseEstimate(Detection(name, score, np.zeros(4)), rotation,
                         np.array([0.1 * k, 0, 1.0]))
            for k, (name, score) in enumerate(zip(names, scores))]


def test_detections_are_named_as_their_tf_frames_and_carry_a_covariance(lmo_models):
    header = Header(frame_id='cam')
    poses = _poses(('ape', 'glue', 'ape'), (0.75, 0.5, 0.25))
    pose_msgs = conversions.poses_to_messages(poses)
    prefix = resolve_prefix('~/', '/cam1/bbpose_node')
    array = DetectionsBuilder(lmo_models)(header, poses, pose_msgs, prefix)
    names = ['cam1/bbpose_node/ape', 'cam1/bbpose_node/glue', 'cam1/bbpose_node/ape_1']
    assert [d.id for d in array.detections] == names
    assert [t.child_frame_id for t in transforms(header, poses, pose_msgs, prefix).transforms
            ] == names
    covariances = [np.array(d.results[0].pose.covariance).reshape(6, 6)
                   for d in array.detections]
    for covariance in covariances:
        assert np.all(np.diag(covariance) > 0)
        assert np.allclose(covariance, np.diag(np.diag(covariance)))
    # The less confident ape pose reports the larger spread.
    assert np.all(np.diag(covariances[2]) > np.diag(covariances[0]))


def test_the_tf_prefix_stands_for_the_node_name_by_default():
    assert resolve_prefix('~/', '/cam1/bbpose_node') == 'cam1/bbpose_node/'
    assert resolve_prefix('~/objects/', '/bbpose_node') == 'bbpose_node/objects/'
    assert resolve_prefix('bbpose/', '/bbpose_node') == 'bbpose/'
    assert resolve_prefix('', '/bbpose_node') == ''


def test_the_pose_spread_is_measured_for_every_object_and_scaled_by_confidence(lmo_models):
    spread = load_pose_spread()
    assert set(spread) == set(lmo_models), POSE_SPREAD_FILE
    assert 'bbpose pose-spread' in json.loads(POSE_SPREAD_FILE.read_text())['source']
    for name, entry in spread.items():
        assert all(0 < s < lmo_models[name].diameter for s in entry.sigma_m), name
        assert all(0 < s < np.pi for s in entry.sigma_rad), name
    typical = ObjectSpread((0.01, 0.01, 0.05), (0.1, 0.1, 0.1), 0.8)
    assert np.allclose(np.diag(np.reshape(typical.covariance(0.8), (6, 6))),
                       [1e-4, 1e-4, 25e-4, 0.01, 0.01, 0.01])
    assert np.allclose(typical.covariance(0.4), np.multiply(typical.covariance(0.8), 4))
    assert np.all(np.isfinite(typical.covariance(0.0)))
    # An object without a measured spread reports none (all zero).
    poses = _poses(('ape',), (0.5,))
    array = DetectionsBuilder(lmo_models, {})(Header(), poses,
                                              conversions.poses_to_messages(poses))
    assert list(array.detections[0].results[0].pose.covariance) == [0.0] * 36


def test_markers_are_cleared_by_one_deleteall():
    message = conversions.delete_all_markers(Header(frame_id='cam'))
    assert [(m.action, m.header.frame_id) for m in message.markers] == [
        (Marker.DELETEALL, 'cam')]


def test_a_starved_input_stays_a_warning_while_it_lasts():
    now = [0.0]
    watch = InputWatch(stale_s=3.0, clock=lambda: now[0])
    stats = NodeStats()
    assert watch.conditions('/image') == []            # not serving: nothing to watch
    watch.start()
    watch.incompatible('a publisher on /image offers QoS incompatible')
    levels = []
    for second in range(1, 11):                       # 10 s, nothing arriving
        now[0] = float(second)
        levels.append(stats.status('n', conditions=watch.conditions('/image')).level)
    assert levels == [DiagnosticStatus.WARN] * 10
    assert 'no image on /image for 10 s' in stats.status(
        'n', conditions=watch.conditions('/image')).message
    watch.image()                                     # images again: the conditions end
    assert watch.conditions('/image') == []
    assert stats.status('n', conditions=watch.conditions('/image')).level == \
        DiagnosticStatus.OK
    now[0] = 14.5
    assert watch.conditions('/image') == ['no image on /image for 4 s']
    watch.stop()
    assert watch.conditions('/image') == []


def test_the_qos_warning_names_only_the_policy_that_differs():
    text = incompatible_qos_text('/camera/image_raw', 'reliability', 'reliable')
    assert 'reliability policy' in text and 'qos_reliability (now reliable)' in text
    assert 'qos_depth' not in text
    text = incompatible_qos_text('/camera/image_raw', 'durability', 'reliable')
    assert "the publisher's durability" in text
    assert 'qos_reliability' not in text and 'qos_depth' not in text


@dataclasses.dataclass(frozen=True)
class _Config:
    values: dict

    def updated(self, changes, options):
        return _Config({**self.values, **changes})


def _wait(done):
    deadline = time.monotonic() + 10.0
    while not done() and time.monotonic() < deadline:
        time.sleep(0.01)
    return done()


def test_a_rebuild_swaps_config_and_pipeline_or_sets_the_values_back():
    gate, set_back, refused = threading.Event(), [], []

    def build(config):
        assert gate.wait(10.0)
        if config.values['objects'] == ['teapot']:
            raise InputError('no teapot')
        return f'pipeline of {config.values["objects"]}'

    rebuilder = PipelineRebuilder(build, set_back.append, log=lambda text: None,
                                  refuse=lambda names, text: refused.append(text))
    assert rebuilder.needed({'objects': ['ape']}) == {}           # unconfigured
    rebuilder.install(_Config({'objects': ['ape']}), 'pipeline of ape')
    assert rebuilder.needed({'objects': ['ape']}) == {}           # what it has already
    rebuilder.request({'objects': ['can']}, None)
    assert rebuilder.pipeline == 'pipeline of ape'                # held at the gate
    gate.set()
    assert _wait(lambda: rebuilder.pipeline == "pipeline of ['can']")
    assert rebuilder.config.values == {'objects': ['can']}
    rebuilder.request({'objects': ['teapot']}, None)
    assert _wait(lambda: set_back)
    assert set_back == [{'objects': ['can']}] and 'no teapot' in refused[0]
    assert rebuilder.pipeline == "pipeline of ['can']"
    rebuilder.release()
    assert rebuilder.config is None and rebuilder.pipeline is None


@pytest.mark.slow   # waits out a pipeline build, ~10 s
def test_a_build_begun_before_a_cleanup_is_thrown_away():
    gate = threading.Event()
    rebuilder = PipelineRebuilder(lambda config: gate.wait(10.0) and 'new', lambda v: None,
                                  log=lambda text: None, refuse=lambda names, text: None)
    rebuilder.install(_Config({'objects': ['ape']}), 'old')
    rebuilder.request({'objects': ['can']}, None)
    rebuilder.release()
    rebuilder.install(_Config({'objects': ['ape']}), 'configured again')
    gate.set()
    assert not _wait(lambda: rebuilder.pipeline == 'new')
    assert rebuilder.pipeline == 'configured again'


@pytest.fixture
def idle_node(lmo_root):
    """Make a BBPoseNode in this process: unconfigured (nothing loaded), never spun."""
    context = Context()
    rclpy.init(context=context)
    node = node_module.BBPoseNode(context=context, parameter_overrides=[
        Parameter('autostart', value=False), Parameter('dataset_dir', value=str(lmo_root))])
    yield node
    node.destroy_node()
    rclpy.try_shutdown(context=context)


def change_state(node, transition_id):
    """Call the node's change_state service callback as the executor would."""
    request = ChangeState.Request(transition=Transition(id=transition_id))
    return node._service_change_state.callback(request, ChangeState.Response()).success


def test_an_invalid_transition_id_is_refused_and_the_node_keeps_its_state(idle_node):
    for transition_id in (Transition.TRANSITION_ACTIVATE, Transition.TRANSITION_DEACTIVATE,
                          Transition.TRANSITION_CLEANUP, 99):
        assert not change_state(idle_node, transition_id)
        assert idle_node._state_machine.current_state[1] == 'unconfigured'


def test_a_set_of_an_unknown_parameter_is_refused_naming_it(idle_node):
    request = SetParameters.Request(
        parameters=[Parameter('no_such_parameter', value=1).to_parameter_msg()])
    response = idle_node._parameter_service._set_parameters_callback(
        request, SetParameters.Response())
    result = response.results[0]
    assert not result.successful
    assert 'parameter no_such_parameter does not exist' in result.reason, result.reason
    status = idle_node.stats.status('n', idle_node.lifecycle_state)
    assert counts_from_status(status)['parameters_refused'] == 1


def test_diagnostics_say_finalized_after_shutdown(idle_node):
    assert change_state(idle_node, Transition.TRANSITION_UNCONFIGURED_SHUTDOWN)
    assert idle_node._state_machine.current_state[1] == 'finalized'
    status = idle_node.stats.status('n', idle_node.lifecycle_state)
    assert {v.key: v.value for v in status.values}['lifecycle_state'] == 'finalized'
    assert not change_state(idle_node, Transition.TRANSITION_CONFIGURE)
