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

"""The ROS adapter's parts without a graph: pairing, throttling, conversions, parameters."""

from pathlib import Path
import re

from diagnostic_msgs.msg import DiagnosticStatus
import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter
from rclpy.qos import QoSReliabilityPolicy
from std_msgs.msg import Header
from visualization_msgs.msg import Marker
import yaml

from bbpose_ros.bags.topics import DEFAULT_FRAME_ID
from bbpose_ros.core.data.stamps import BACKWARDS, FUTURE, REPEATED, StampChecker
from bbpose_ros.core.geometry.rotations import quat_wxyz_to_matrix, xyzw_to_wxyz
from bbpose_ros.core.pipeline.poses import Detection, PoseEstimate
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.ros import conversions
from bbpose_ros.ros.detections import DetectionsBuilder, instance_names, transforms
from bbpose_ros.ros.diagnostics import counts_from_status, NodeStats, timings_from_status
from bbpose_ros.ros.pairing import NEWER_PAIRED, Pairing, QUEUE_FULL, StampPairer
from bbpose_ros.ros.param_specs import APPLIES
from bbpose_ros.ros.params import check_value, checked_options, declare_parameters
from bbpose_ros.ros.params import parameter_values, PARAMETERS, read_config
from bbpose_ros.ros.params_file import read_params_file
from bbpose_ros.ros.throttle import KeyedThrottle, ProblemLog

SECOND = 1_000_000_000


def test_pairs_by_stamp_within_slop_in_either_order():
    pairer = StampPairer()
    assert pairer.add_image(5 * SECOND, 'image5', 0.01) == Pairing()
    assert pairer.add_info(7 * SECOND, 'info7', 0.01) == Pairing()     # other stamp: no pair
    assert pairer.add_info(5 * SECOND + 5_000_000, 'info5', 0.01) == Pairing(
        pairs=[('image5', 'info5')])
    assert pairer.add_image(7 * SECOND, 'image7', 0.01) == Pairing(pairs=[('image7', 'info7')])
    assert pairer.waiting == []


def test_images_wait_in_a_queue_for_late_camera_infos():
    # 5 Hz, each CameraInfo 0.25 s late: the next image arrives before it, and both pair.
    pairer = StampPairer()
    pairs, dropped = [], []
    events = sorted([(k * 0.2, 'image', k) for k in range(25)]
                    + [(k * 0.2 + 0.25, 'info', k) for k in range(25)])
    for _, kind, k in events:
        offer = pairer.add_image if kind == 'image' else pairer.add_info
        pairing = offer(k * SECOND // 5, f'{kind}{k}', 0.01)
        pairs += pairing.pairs
        dropped += pairing.dropped
    assert pairs == [(f'image{k}', f'info{k}') for k in range(25)] and dropped == []


def test_a_newer_image_paired_first_drops_the_older_waiting_ones():
    pairer = StampPairer()
    pairer.add_image(1 * SECOND, 'image1', 0.01)
    pairer.add_image(2 * SECOND, 'image2', 0.01)
    assert pairer.waiting == ['image1', 'image2']
    assert pairer.add_info(2 * SECOND, 'info2', 0.01) == Pairing(
        pairs=[('image2', 'info2')], dropped=[('image1', NEWER_PAIRED)])
    assert pairer.add_info(1 * SECOND, 'info1', 0.01) == Pairing()   # never out of order
    pairer.add_image(3 * SECOND, 'image3', 0.01)
    pairer.add_info(4 * SECOND, 'info4', 0.01)
    assert pairer.add_image(4 * SECOND, 'image4', 0.01) == Pairing(
        pairs=[('image4', 'info4')], dropped=[('image3', NEWER_PAIRED)])


def test_the_waiting_queue_is_bounded_in_length_and_time():
    now = [0.0]
    pairer = StampPairer(max_waiting=3, clock=lambda: now[0])
    for k in range(3):
        assert pairer.add_image(k * SECOND, k, 0.01) == Pairing()
    assert pairer.add_image(3 * SECOND, 3, 0.01) == Pairing(dropped=[(0, QUEUE_FULL)])
    now[0] = 4.0
    assert pairer.add_image(4 * SECOND, 4, 0.01) == Pairing(dropped=[(1, QUEUE_FULL)])
    now[0] = 5.5
    assert pairer.expire(5.0) == [2, 3] and pairer.waiting == [4]


def test_negative_slop_takes_the_latest_info():
    pairer = StampPairer()
    pairer.add_info(1 * SECOND, 'first', -1.0)
    pairer.add_info(2 * SECOND, 'latest', -1.0)
    assert pairer.add_image(50 * SECOND, 'image', -1.0) == Pairing(pairs=[('image', 'latest')])
    pairer = StampPairer()                         # images before any CameraInfo wait for one
    pairer.add_image(1 * SECOND, 'a', -1.0)
    pairer.add_image(2 * SECOND, 'b', -1.0)
    assert pairer.add_info(9 * SECOND, 'info', -1.0).pairs == [('a', 'info'), ('b', 'info')]


def test_throttle_is_per_key():
    now = [0.0]
    throttle = KeyedThrottle(period_s=5.0, clock=lambda: now[0])
    assert throttle.allow('encoding') and throttle.allow('step')
    assert not throttle.allow('encoding')
    now[0] = 5.0
    assert throttle.allow('encoding')


def test_throttle_forgets_expired_keys_beyond_its_bound():
    now = [0.0]
    throttle = KeyedThrottle(period_s=5.0, clock=lambda: now[0], max_keys=10)
    for k in range(100):                  # ever-different messages, one a second
        now[0] = float(k)
        assert throttle.allow(f'data has {k} bytes')
    assert len(throttle) <= 10
    assert not throttle.allow('data has 99 bytes')     # a live key is kept


def test_problems_are_all_counted_and_logged_throttled_per_counter_and_key():
    counted, logged = [], []

    class Logger:
        def warning(self, text):
            logged.append(('warning', text))

        def error(self, text):
            logged.append(('error', text))

    problems = ProblemLog(counted.append, Logger(), KeyedThrottle(clock=lambda: 0.0))
    for _ in range(3):
        problems.drop('bad_image', 'encoding', 'bad encoding')
    problems.drop('bad_image', 'step', 'bad step')
    problems.warn('unpaired', 'encoding', 'no camera_info')
    assert counted == ['bad_image'] * 4 + ['unpaired']
    assert logged == [('error', 'bad encoding'), ('error', 'bad step'),
                      ('warning', 'no camera_info')]


def test_markers_structure(lmo_models):
    header = Header(frame_id='cam')
    header.stamp.sec, header.stamp.nanosec = 12, 345
    rotation = quat_wxyz_to_matrix([0.9, 0.1, -0.3, 0.2])
    poses = [PoseEstimate(Detection(name, 0.75, np.zeros(4)), rotation, np.array([0, 0, 1.0]))
             for name in ('ape', 'ape', 'glue')]
    markers = conversions.MarkerArrayBuilder(lmo_models)(header, poses).markers
    assert markers[0].action == Marker.DELETEALL
    boxes = [m for m in markers if m.type == Marker.LINE_LIST]
    labels = [m for m in markers if m.type == Marker.TEXT_VIEW_FACING]
    assert [(m.ns, m.id) for m in boxes] == [('ape', 0), ('ape', 2), ('glue', 0)]
    assert [(m.ns, m.id) for m in labels] == [('ape', 1), ('ape', 3), ('glue', 1)]
    assert all(len(m.points) == 24 for m in boxes)
    assert labels[0].text == 'ape 0.75'
    assert boxes[0].color == boxes[1].color != boxes[2].color
    assert all(m.header.frame_id == 'cam' and m.header.stamp.nanosec == 345 for m in markers)
    # points are the box corners in the model frame; the marker pose is the estimate
    corners = lmo_models['ape'].box_corners
    points = np.array([[p.x, p.y, p.z] for p in boxes[0].points])
    assert np.allclose(np.unique(points, axis=0), np.unique(corners, axis=0))


def test_detections_and_transforms_of_a_frame(lmo_models):
    header = Header(frame_id='cam')
    header.stamp.sec = 7
    rotations = [quat_wxyz_to_matrix(q) for q in ([0.9, 0.1, -0.3, 0.2], [0.5, 0.5, -0.5, 0.5],
                                                  [1.0, 0.0, 0.0, 0.0])]
    translations = [np.array([0.1, -0.05, 0.8]), np.array([0, 0, 1.0]), np.array([0.2, 0, 1])]
    poses = [PoseEstimate(Detection(name, score, np.zeros(4)), rotation, translation)
             for name, score, rotation, translation in zip(('ape', 'glue', 'ape'),
                                                           (0.75, 0.5, 0.25), rotations,
                                                           translations)]
    pose_msgs = conversions.poses_to_messages(poses)
    array = DetectionsBuilder(lmo_models)(header, poses, pose_msgs)
    assert array.header == header and len(array.detections) == 3
    corners = lmo_models['ape'].box_corners
    for detection, pose, pose_msg in zip(array.detections, poses, pose_msgs):
        assert detection.header == header and len(detection.results) == 1
        result = detection.results[0]
        assert (result.hypothesis.class_id, result.hypothesis.score) == (
            pose.object_name, pose.confidence)
        assert result.pose.pose == pose_msg and detection.bbox.center.orientation == \
            pose_msg.orientation
    box = array.detections[0].bbox
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    assert np.allclose([box.size.x, box.size.y, box.size.z], hi - lo)
    # the centre of the posed box: the mean of its 8 posed corners
    centre = (corners @ rotations[0].T + translations[0]).mean(axis=0)
    assert np.allclose([box.center.position.x, box.center.position.y,
                        box.center.position.z], centre)

    assert instance_names(poses) == ['ape', 'glue', 'ape_1']
    tf = transforms(header, poses, pose_msgs, 'bbpose/').transforms
    assert [t.child_frame_id for t in tf] == ['bbpose/ape', 'bbpose/glue', 'bbpose/ape_1']
    assert all(t.header == header for t in tf)
    assert tf[1].transform.rotation == pose_msgs[1].orientation
    assert (tf[2].transform.translation.x, tf[2].transform.translation.z) == (0.2, 1.0)


def test_pose_messages_use_ros_quaternion_order():
    rotation = quat_wxyz_to_matrix([0.5, 0.5, -0.5, 0.5])
    pose = PoseEstimate(Detection('ape', 0.9, np.zeros(4)), rotation, np.array([0.1, -0.2, 0.9]))
    message, = conversions.poses_to_messages([pose])
    q = message.orientation
    assert np.allclose(quat_wxyz_to_matrix(xyzw_to_wxyz([q.x, q.y, q.z, q.w])), rotation)
    assert (message.position.x, message.position.z) == (0.1, 0.9)


def test_diagnostics_round_trip():
    stats = NodeStats()
    stats.count('received')
    stats.count('bad_image')
    stats.add_timings({'detector': 4.0, 'total': 6.0})
    status = stats.status('bbpose_node: pose pipeline')
    assert status.level == DiagnosticStatus.WARN
    assert counts_from_status(status)['bad_image'] == 1
    assert timings_from_status(status)['detector'] == {'median': 4.0, 'p95': 4.0}
    assert stats.status('again').level == DiagnosticStatus.OK


def test_params_file_blocks_and_overrides(tmp_path):
    path = tmp_path / 'p.yaml'
    path.write_text('/**:\n  ros__parameters:\n    max_instances: 2\n    device: cpu\n'
                    'bbpose_node:\n  ros__parameters:\n    max_instances: 3\n')
    values = read_params_file(path, ['objects:=[ape, glue]'])
    assert values['max_instances'] == 3 and values['objects'] == ['ape', 'glue']
    assert values['sync_slop'] == 0.01       # declared default
    with pytest.raises(InputError, match='not found'):
        read_params_file(tmp_path / 'missing.yaml')


@pytest.fixture
def ros_context():
    context = Context()
    rclpy.init(context=context)
    yield context
    rclpy.try_shutdown(context=context)


def declare(context, **values):
    """Declare the node's parameters on a plain node with overrides; returns NodeConfig."""
    node = rclpy.create_node('params_under_test', context=context, parameter_overrides=[
        Parameter(name, value=value) for name, value in values.items()])
    try:
        declare_parameters(node)
        return read_config(parameter_values(node))
    finally:
        node.destroy_node()


def test_declared_parameters_validate_and_set_qos(ros_context, lmo_root):
    config = declare(ros_context, dataset_dir=str(lmo_root), qos_reliability='best_effort',
                     qos_depth=3, objects=['ape'])
    assert config.qos.reliability == QoSReliabilityPolicy.BEST_EFFORT
    assert config.qos.depth == 3 and config.objects == ('ape',)
    assert config.detector_weights is None          # the shipped file
    with pytest.raises(InputError, match='qos_reliability'):
        declare(ros_context, dataset_dir=str(lmo_root), qos_reliability='sometimes')
    with pytest.raises(InputError, match='device'):
        declare(ros_context, dataset_dir=str(lmo_root), device='tpu')


def test_check_value_names_the_parameter_and_the_problem():
    check_value('score_threshold', 0.5)
    check_value('score_threshold', 1.5)     # a setting's value is checked by its options
    with pytest.raises(InputError, match=re.escape('parameter score_threshold: 1.5 is out of '
                                                   'range [0.0, 1.0]')):
        checked_options({**{n: s.default for n, s in PARAMETERS.items()},
                         'score_threshold': 1.5})
    for name, value, words in [('score_threshold', 'high', 'is not of type double'),
                               ('score_threshold', 1, 'is not of type double'),
                               ('objects', [], 'at least one'),
                               ('objects', ['ape', 'ape'], 'ape listed more than once'),
                               ('qos_reliability', 'sometimes', 'not one of reliable'),
                               ('tf_prefix', '/bbpose/', 'starts with "/"'),
                               ('tf_prefix', 'my cam', 'whitespace'),
                               ('qnet_weights', '/nonexistent.pt', 'not found')]:
        with pytest.raises(InputError, match=f'parameter {name}: .*{re.escape(words)}'):
            check_value(name, value)


def test_the_yaml_documents_every_parameter_and_when_it_is_read():
    text = (Path(__file__).parents[1] / 'config' / 'bbpose.yaml').read_text()
    values = yaml.safe_load(text)['/**']['ros__parameters']
    assert set(values) == set(PARAMETERS)
    lines = text.splitlines()
    for name, spec in PARAMETERS.items():
        at = next(k for k, line in enumerate(lines) if line.strip().startswith(f'{name}:'))
        comment = next(line for line in reversed(lines[:at]) if line.strip().startswith('#')
                       and line.rstrip().endswith('.'))
        assert comment.rstrip().endswith(f'{spec.applies.capitalize()}.'), name
        check_value(name, values[name])


def test_the_rviz_config_shows_the_node_outputs():
    root = Path(__file__).parents[1]
    config = yaml.safe_load((root / 'config' / 'bbpose.rviz').read_text())
    displays = {d['Class'].split('/')[-1]: d for d in config['Visualization Manager']['Displays']}
    assert displays['Image']['Topic']['Value'] == '/bbpose_node/debug_image'
    assert displays['MarkerArray']['Topic']['Value'] == '/bbpose_node/markers'
    assert displays['TF']['Enabled']
    assert config['Visualization Manager']['Global Options']['Fixed Frame'] == DEFAULT_FRAME_ID
    assert "'bbpose.rviz'" in (root / 'launch' / 'bbpose.launch.py').read_text()


def test_stamp_checker_tells_repeated_backward_and_future_stamps():
    checker = StampChecker(future_tolerance_ns=SECOND)
    now = 100 * SECOND
    assert checker.check(50 * SECOND, now) is None
    assert checker.check(50 * SECOND, now)[0] == REPEATED
    kind, text = checker.check(49 * SECOND, now)
    assert kind == BACKWARDS and '1.000 s older' in text and 'header.stamp' in text
    assert checker.check(60 * SECOND, now) is None          # newer again: fine
    assert checker.check(now + SECOND, now) is None         # within the tolerance
    kind, text = checker.check(now + 5 * SECOND, now)
    assert kind == FUTURE and '5.000 s ahead' in text


def test_what_shapes_the_pipeline_at_run_time_is_a_setting_but_the_object_list():
    settings = {name for name, spec in PARAMETERS.items() if spec.option}
    pipeline = {name for name, spec in PARAMETERS.items() if spec.applies == 'pipeline'}
    assert pipeline - {'objects'} <= settings


def test_the_yaml_documents_the_declared_defaults():
    values = yaml.safe_load((Path(__file__).parents[1] / 'config' / 'bbpose.yaml').read_text())
    documented = values['/**']['ros__parameters']
    assert list(documented) == list(PARAMETERS)
    for name, spec in PARAMETERS.items():
        assert documented[name] == spec.default, name
        assert type(documented[name]) is type(spec.default), name
    assert {spec.applies for spec in PARAMETERS.values()} <= set(APPLIES)
