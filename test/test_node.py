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
bbpose_node as users run it: a separate process fed from a bag of LM-O frames.

One node serves the whole module; the tests run in file order and the last one stops it
with SIGINT.
"""

import signal

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
import numpy as np
import pytest
from rclpy.serialization import deserialize_message
from rosbags.rosbag2 import Reader
from sensor_msgs.msg import CameraInfo, Image
from test_ros_support import GraphClient, NodeLog, TIMEOUT_S, use_private_domain, weight_files
from test_ros_support import write_params
from tf2_msgs.msg import TFMessage
from vision_msgs.msg import Detection3DArray
from visualization_msgs.msg import Marker, MarkerArray

from bbpose_ros.bags import topics
from bbpose_ros.bags.player import BagPlayer
from bbpose_ros.bags.reader import read_bag_frames
from bbpose_ros.bags.writer import write_bop_bag
from bbpose_ros.cli.graph.replay import NodeProcess
from bbpose_ros.core.data.models import LMO_OBJECTS
from bbpose_ros.core.data.stamps import stamp_to_ns
from bbpose_ros.core.geometry.rotations import quat_wxyz_to_matrix, xyzw_to_wxyz
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.pipeline.loader import load_pipeline, WeightFiles
from bbpose_ros.ros.diagnostics import counts_from_status, DROPS

pytestmark = pytest.mark.slow   # starts bbpose_node as a process

FRAMES = 4
START_NS = 1_700_000_000 * 1_000_000_000
OUT = '/bbpose_node'
MARKERS = f'{OUT}/markers'
DEBUG = f'{OUT}/debug_image'
DETECTIONS = f'{OUT}/detections'


@pytest.fixture(scope='module')
def bag(lmo, tmp_path_factory):
    path = tmp_path_factory.mktemp('bag') / 'lmo'
    write_bop_bag(lmo.frames()[:FRAMES], path, start_stamp_ns=START_NS, progress=False)
    return path


@pytest.fixture(scope='module')
def weights(tmp_path_factory):
    return weight_files(tmp_path_factory.mktemp('weights'))


@pytest.fixture(scope='module')
def graph(lmo_root, weights, tmp_path_factory):
    """Start the node and a client wired to its topics; stop both at the end."""
    use_private_domain(offset=0)
    folder = tmp_path_factory.mktemp('node')
    log = NodeLog(folder / 'node.log')
    node = NodeProcess(write_params(folder / 'params.yaml', lmo_root, weights),
                       stderr=log.file)
    client = GraphClient()
    client.image = client.publisher(Image, topics.IMAGE_TOPIC)
    client.info = client.publisher(CameraInfo, topics.CAMERA_INFO_TOPIC)
    for name in LMO_OBJECTS:
        client.subscribe(PoseStamped, f'{OUT}/{name}/pose')
    client.subscribe(MarkerArray, MARKERS)
    client.subscribe(Detection3DArray, DETECTIONS)
    client.subscribe(TFMessage, '/tf')
    client.subscribe(Image, DEBUG)
    client.subscribe(DiagnosticArray, '/diagnostics')
    assert client.connected((client.image, client.info), DEBUG), log.path
    assert client.spin_until(client.matched), log.path   # every output's first message
    yield client, node, log
    client.close()
    node.stop()


def answered(client, stamp_ns):
    """Return whether the node's MarkerArray for the stamp arrived."""
    return any(stamp_to_ns(m.markers[0].header.stamp) == stamp_ns
               for m in client.received[MARKERS])


def good_frame(bag_frames_raw, stamp_ns):
    """Return (Image, CameraInfo) of the bag's first frame, restamped."""
    image = deserialize_message(bag_frames_raw[topics.IMAGE_TOPIC], Image)
    info = deserialize_message(bag_frames_raw[topics.CAMERA_INFO_TOPIC], CameraInfo)
    for message in (image, info):
        message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp_ns, 10 ** 9)
    return image, info


@pytest.fixture(scope='module')
def first_frame(bag):
    """Raw CDR of the bag's first message on each topic."""
    raw = {}
    with Reader(bag) as reader:
        for connection, _, data in reader.messages():
            raw.setdefault(connection.topic, bytes(data))
    return raw


def send_and_wait(client, image, info):
    client.image.publish(image)
    if info is not None:
        client.info.publish(info)
    return client.spin_until(lambda: answered(client, stamp_to_ns(image.header.stamp)))


def test_image_without_camera_info_is_not_answered(graph, first_frame):
    client, _, log = graph
    image, _ = good_frame(first_frame, START_NS + 100 * 10 ** 9)
    log.mark()
    client.image.publish(image)
    # first in the module: the node has never seen a CameraInfo
    assert log.wait_for('WARN', 'image dropped', 'camera_info'), log.path
    assert not answered(client, stamp_to_ns(image.header.stamp))
    assert send_and_wait(client, *good_frame(first_frame, START_NS + 101 * 10 ** 9))


def test_every_bag_frame_answered_like_the_offline_pipeline(graph, bag, lmo_models, weights):
    client, _, log = graph
    player = BagPlayer(client.node, bag)
    stamps = []
    for topic, _, raw in player.messages():
        if topic == topics.IMAGE_TOPIC:
            if stamps:
                assert client.spin_until(lambda: answered(client, stamps[-1])), log.path
            stamps.append(stamp_to_ns(deserialize_message(raw, Image).header.stamp))
        player.publish(topic, raw)
    assert client.spin_until(lambda: answered(client, stamps[-1]))
    assert client.spin_until(lambda: set(stamps) <= {stamp_to_ns(m.header.stamp)
                                                     for m in client.received[DEBUG]})

    frames = read_bag_frames(bag)
    # The node's defaults (refinement of each detection's best hypotheses), score 0.
    pipeline = load_pipeline(lmo_models, PipelineOptions(score_threshold=0.0),
                             WeightFiles(*weights))
    poses = {name: client.received[f'{OUT}/{name}/pose'] for name in LMO_OBJECTS}
    for frame in frames:
        expected = pipeline.estimate(frame.image_rgb, frame.camera).poses
        assert expected, 'the comparison needs poses'
        for name in LMO_OBJECTS:
            mine = [p for p in poses[name] if stamp_to_ns(p.header.stamp) == frame.stamp_ns]
            theirs = [p for p in expected if p.object_name == name]
            assert len(mine) == len(theirs)
            for message, pose in zip(mine, theirs):
                assert message.header.frame_id == frame.frame_id
                q = message.pose.orientation
                rotation = quat_wxyz_to_matrix(xyzw_to_wxyz([q.x, q.y, q.z, q.w]))
                position = message.pose.position
                assert np.allclose(rotation, pose.rotation, atol=1e-5)
                assert np.allclose([position.x, position.y, position.z], pose.translation,
                                   atol=1e-5)
    for topic in (MARKERS, DEBUG):
        got = {(stamp_to_ns(m.markers[0].header.stamp if topic == MARKERS else m.header.stamp),
                m.markers[0].header.frame_id if topic == MARKERS else m.header.frame_id)
               for m in client.received[topic]}
        assert {(f.stamp_ns, f.frame_id) for f in frames} <= got


def pose_values(pose):
    """(x, y, z, qx, qy, qz, qw) of a geometry_msgs/Pose."""
    p, q = pose.position, pose.orientation
    return (p.x, p.y, p.z, q.x, q.y, q.z, q.w)


def test_detections_and_tf_carry_the_poses_of_the_pose_topics(graph, bag):
    """The bag replayed above: per frame, one Detection3D and one TF frame per PoseStamped."""
    client = graph[0]
    frames = {f.stamp_ns: f.frame_id for f in read_bag_frames(bag)}

    def by_stamp(topic, header_of):
        return {stamp_to_ns(header_of(m).stamp): m for m in client.received[topic]
                if stamp_to_ns(header_of(m).stamp) in frames}

    assert client.spin_until(lambda: len(by_stamp(DETECTIONS, lambda m: m.header)) == len(frames))
    detections = by_stamp(DETECTIONS, lambda m: m.header)
    transforms = by_stamp('/tf', lambda m: m.transforms[0].header)
    for stamp, frame_id in frames.items():
        stamped = sorted((name, pose_values(m.pose)) for name in LMO_OBJECTS
                         for m in client.received[f'{OUT}/{name}/pose']
                         if stamp_to_ns(m.header.stamp) == stamp)
        assert stamped, 'the comparison needs poses'
        array = detections[stamp]
        assert array.header.frame_id == frame_id
        assert sorted((d.results[0].hypothesis.class_id, pose_values(d.results[0].pose.pose))
                      for d in array.detections) == stamped
        assert all(d.header == array.header and 0 <= d.results[0].hypothesis.score <= 1
                   and min(d.bbox.size.x, d.bbox.size.y, d.bbox.size.z) > 0.01
                   for d in array.detections)
        tf = transforms[stamp].transforms
        assert {t.header.frame_id for t in tf} == {frame_id}
        # The children are prefixed with the node's name by default (tf_prefix '~/').
        assert sorted((t.child_frame_id.removeprefix(f'{OUT[1:]}/'), (
            t.transform.translation.x, t.transform.translation.y, t.transform.translation.z,
            t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z,
            t.transform.rotation.w)) for t in tf) == stamped
        assert all(t.child_frame_id.startswith(f'{OUT[1:]}/') for t in tf)
        # Each Detection3D is named as its TF frame and reports its spread.
        assert sorted(d.id for d in array.detections) == sorted(t.child_frame_id for t in tf)
        assert all(min(d.results[0].pose.covariance[::7]) > 0 for d in array.detections)


def test_marker_array_structure(graph):
    client = graph[0]
    message = client.received[MARKERS][-1]
    assert message.markers[0].action == Marker.DELETEALL
    boxes = [m for m in message.markers if m.type == Marker.LINE_LIST]
    labels = [m for m in message.markers if m.type == Marker.TEXT_VIEW_FACING]
    assert boxes and len(boxes) == len(labels) == (len(message.markers) - 1) // 2
    assert all(len(m.points) == 24 for m in boxes)
    assert len({(m.ns, m.id) for m in message.markers[1:]}) == len(message.markers) - 1
    assert {m.ns for m in boxes} <= set(LMO_OBJECTS)
    assert all(m.text.split()[0] == m.ns for m in labels)


def test_diagnostics_report_latency_and_counts(graph):
    client = graph[0]

    def keys(message):
        return {value.key for status in message.status for value in status.values}

    assert client.spin_until(lambda: any('total_ms_median' in keys(m)
                                         for m in client.received['/diagnostics']))
    last = [m for m in client.received['/diagnostics'] if 'total_ms_median' in keys(m)][-1]
    assert {'frames_received', 'frames_answered', 'frames_superseded', 'detector_ms_p95',
            'node_ms_p95'} <= keys(last)
    assert last.status[0].name == 'bbpose_node: pose pipeline'


def test_camera_info_with_another_stamp_is_not_paired(graph, first_frame):
    client, _, log = graph
    image, info = good_frame(first_frame, START_NS + 200 * 10 ** 9)
    info.header.stamp.sec += 1
    log.mark()
    client.image.publish(image)
    client.info.publish(info)
    assert log.wait_for('WARN', 'image dropped', 'differs by 1.000 s'), log.path
    assert not answered(client, stamp_to_ns(image.header.stamp))
    assert send_and_wait(client, *good_frame(first_frame, START_NS + 201 * 10 ** 9))


def _bad_encoding(image, info):
    image.encoding = 'rgb16'


def _bad_step(image, info):
    image.step -= 1


def _bad_data_length(image, info):
    image.data = image.data[:-7]


def _zero_size(image, info):
    image.height = image.width = image.step = 0
    image.data = []


def _zero_k(image, info):
    info.k = [0.0] * 9


@pytest.mark.parametrize('spoil, field', [
    (_bad_encoding, 'field encoding'), (_bad_step, 'field step'),
    (_bad_data_length, 'field data'), (_zero_size, 'fields height, width'),
    (_zero_k, 'field k')])
def test_bad_input_is_logged_and_the_next_good_frame_answered(graph, first_frame, spoil,
                                                              field):
    client, node, log = graph
    second = 300 + [_bad_encoding, _bad_step, _bad_data_length, _zero_size,
                    _zero_k].index(spoil) * 2
    image, info = good_frame(first_frame, START_NS + second * 10 ** 9)
    spoil(image, info)
    log.mark()
    client.image.publish(image)
    client.info.publish(info)
    assert log.wait_for('ERROR', 'image dropped', field), log.path
    assert send_and_wait(client, *good_frame(first_frame, START_NS + (second + 1) * 10 ** 9))
    assert not answered(client, stamp_to_ns(image.header.stamp))
    node.check_alive()


def test_a_burst_is_not_queued_and_every_frame_is_accounted_for(graph, first_frame):
    client = graph[0]
    frames = [good_frame(first_frame, START_NS + (400 + k) * 10 ** 9) for k in range(10)]
    for image, info in frames:
        client.image.publish(image)
        client.info.publish(info)
    assert client.spin_until(lambda: answered(client, stamp_to_ns(frames[-1][0].header.stamp)))

    def accounted():
        counts = counts_from_status(client.received['/diagnostics'][-1].status[0])
        drops = sum(counts[key] for key in DROPS)
        return counts['received'] == counts['answered'] + drops and counts['answered'] > 0

    assert client.spin_until(accounted)


def test_sigint_stops_the_node_cleanly(graph):
    _, node, _ = graph
    node.process.send_signal(signal.SIGINT)
    # How long a stop takes is measured by ``bbpose bench --graph`` (node.stop_s).
    assert node.process.wait(TIMEOUT_S) == 0
