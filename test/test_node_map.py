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
bbpose_node's map in a fixed frame: TF in, the map of its own poses out, cleared on request.

One node (``fixed_frame: world``) serves the module; a bag of one LM-O static scene, with
its camera poses on /tf as a robot's TF would give them, is played into it frame by frame.
"""

import dataclasses

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
import numpy as np
import pytest
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import CameraInfo, Image
from std_srvs.srv import Trigger
from test_ros_support import GraphClient, NodeLog, use_private_domain, weight_files
from test_ros_support import write_params
from tf2_msgs.msg import TFMessage
from vision_msgs.msg import Detection3DArray
from visualization_msgs.msg import MarkerArray

from bbpose_ros.bags import topics
from bbpose_ros.bags.player import BagPlayer
from bbpose_ros.bags.reader import read_bag_frames
from bbpose_ros.bags.writer import write_bop_bag
from bbpose_ros.cli.graph.replay import NodeProcess
from bbpose_ros.core.data.models import LMO_OBJECTS
from bbpose_ros.core.data.stamps import stamp_to_ns
from bbpose_ros.core.eval.static_stretches import camera_poses, static_stretches
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.pipeline.loader import load_pipeline, WeightFiles
from bbpose_ros.core.scene.object_map import ObjectMap
from bbpose_ros.ros.diagnostics import counts_from_status

pytestmark = pytest.mark.slow   # starts bbpose_node as a process

OUT = '/bbpose_node'
MAP = f'{OUT}/map/detections'
MARKERS = f'{OUT}/markers'
START_NS = 1_700_000_000 * 1_000_000_000


@pytest.fixture(scope='module')
def scene(lmo_frames, lmo_models):
    """Return the first static scene of four frames or more, with its camera poses."""
    stretch = next(s for s in static_stretches(lmo_frames) if len(s) >= 4)[:4]
    return [dataclasses.replace(frame, world_from_camera=pose)
            for frame, pose in zip(stretch, camera_poses(stretch, lmo_models))]


@pytest.fixture(scope='module')
def bag(scene, tmp_path_factory):
    path = tmp_path_factory.mktemp('bag') / 'scene'
    write_bop_bag(scene, path, start_stamp_ns=START_NS, progress=False)
    return path


@pytest.fixture(scope='module')
def graph(lmo_root, tmp_path_factory):
    use_private_domain(offset=15)
    folder = tmp_path_factory.mktemp('node')
    log = NodeLog(folder / 'node.log')
    weights = weight_files(folder)
    node = NodeProcess(write_params(folder / 'params.yaml', lmo_root, weights,
                                    fixed_frame='world'), stderr=log.file)
    client = GraphClient()
    client.image = client.publisher(Image, topics.IMAGE_TOPIC)
    client.info = client.publisher(CameraInfo, topics.CAMERA_INFO_TOPIC)
    client.tf = client.publisher(TFMessage, topics.TF_TOPIC)
    for topic, cls in ((MAP, Detection3DArray), (MARKERS, MarkerArray),
                       ('/diagnostics', DiagnosticArray)):
        client.subscribe(cls, topic)
    for name in LMO_OBJECTS:
        client.subscribe(PoseStamped, f'{OUT}/{name}/pose')
    assert client.connected((client.image, client.info, client.tf), MAP), log.path
    assert client.spin_until(client.matched), log.path   # every output's first message
    yield client, weights, log
    client.close()
    node.stop()


def map_at(client, stamp_ns):
    return next((m for m in client.received[MAP] if stamp_to_ns(m.header.stamp) == stamp_ns),
                None)


def play(client, bag, log):
    """Play the bag frame by frame, each after the previous frame's map arrived."""
    player = BagPlayer(client.node, bag)
    inputs = (topics.TF_TOPIC, topics.IMAGE_TOPIC, topics.CAMERA_INFO_TOPIC)

    def matched():
        return all(player.publishers[topic].get_subscription_count() > 0 for topic in inputs)
    assert client.spin_until(matched)
    last = None
    for topic, _, raw in player.messages():
        if topic == topics.IMAGE_TOPIC:
            if last is not None:
                assert client.spin_until(lambda: map_at(client, last) is not None), log.path
            last = stamp_to_ns(deserialize_message(raw, Image).header.stamp)
        player.publish(topic, raw)
    assert client.spin_until(lambda: map_at(client, last) is not None), log.path


def test_the_node_maps_its_poses_as_the_core_map_does(graph, bag, lmo_models):
    client, weights, log = graph
    play(client, bag, log)
    pipeline = load_pipeline(lmo_models, PipelineOptions(score_threshold=0.0),
                             WeightFiles(*weights))
    expected_map = ObjectMap(lmo_models, pipeline.options)
    for frame in read_bag_frames(bag):
        assert frame.world_from_camera is not None
        expected_map.add_view(frame.stamp_ns, frame.world_from_camera, frame.camera,
                              pipeline.estimate(frame.image_rgb, frame.camera).poses)
        message = map_at(client, frame.stamp_ns)
        assert message.header.frame_id == 'world'
        expected = {o.object_name: o for o in expected_map.objects()}
        got = {d.results[0].hypothesis.class_id: d for d in message.detections}
        assert expected and set(got) == set(expected)
        for name, detection in got.items():
            rotation, translation = topics.pose_from_message(detection.results[0].pose)
            assert np.allclose(translation, expected[name].translation, atol=1e-5)
            assert np.allclose(rotation, expected[name].rotation, atol=1e-5)
            assert detection.id.endswith(f'map/{name}')
            covariance = np.reshape(detection.results[0].pose.covariance, (6, 6))[:3, :3]
            assert np.allclose(covariance, expected[name].covariance, atol=1e-9)


def test_a_frame_tf_cannot_place_is_answered_and_counted(graph, bag):
    client, _, log = graph
    frame = read_bag_frames(bag)[0]
    stamp = START_NS + 3600 * 10 ** 9            # an hour after the bag's TF
    player = BagPlayer(client.node, bag)
    first = {}
    for topic, _, raw in player.messages():
        first.setdefault(topic, raw)
    image = deserialize_message(first[topics.IMAGE_TOPIC], Image)
    info = deserialize_message(first[topics.CAMERA_INFO_TOPIC], CameraInfo)
    for message in (image, info):
        message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp, 10 ** 9)
    log.mark()
    client.image.publish(image)
    client.info.publish(info)
    assert client.spin_until(lambda: any(stamp_to_ns(m.markers[0].header.stamp) == stamp
                                         for m in client.received[MARKERS])), log.path
    assert log.wait_for('WARN', 'no camera pose for the map', frame.frame_id), log.path
    assert map_at(client, stamp) is None

    def counted():
        statuses = [s for m in client.received['/diagnostics'] for s in m.status
                    if s.name.startswith('bbpose_node:')]
        return statuses and counts_from_status(statuses[-1])['map_no_transform'] >= 1
    assert client.spin_until(counted), log.path


def test_a_bad_transform_is_refused_and_clear_map_forgets_the_objects(graph, scene, tmp_path):
    client, _, log = graph
    bag = tmp_path / 'again'
    write_bop_bag(scene, bag, start_stamp_ns=START_NS + 7200 * 10 ** 9, progress=False)
    frames = read_bag_frames(bag)
    bad = deserialize_message(next(raw for topic, _, raw in BagPlayer(client.node, bag).messages()
                                   if topic == topics.TF_TOPIC), TFMessage)
    bad.transforms[0].transform.rotation.w = float('nan')
    log.mark()
    client.tf.publish(bad)
    assert log.wait_for('WARN', '/tf', 'not finite'), log.path
    response = client.call(Trigger, f'{OUT}/clear_map', Trigger.Request())
    assert response is not None and response.success and 'cleared' in response.message
    play(client, bag, log)        # the same scene again, later, into an empty map
    first = map_at(client, frames[0].stamp_ns)
    # One view: the map is that frame's own poses, carried into the fixed frame.
    own = {name: topics.pose_from_message(m) for name in LMO_OBJECTS
           for m in client.received[f'{OUT}/{name}/pose']
           if stamp_to_ns(m.header.stamp) == frames[0].stamp_ns}
    assert first.detections and len(first.detections) == len(own)
    world_from_camera = frames[0].world_from_camera
    for detection in first.detections:
        rotation, translation = own[detection.results[0].hypothesis.class_id]
        in_world = world_from_camera[:3, :3] @ translation + world_from_camera[:3, 3]
        mapped = topics.pose_from_message(detection.results[0].pose)[1]
        assert np.allclose(mapped, in_world, atol=1e-5)


def test_a_frame_waits_for_the_tf_that_comes_after_it(graph, bag):
    client, _, log = graph
    stamp = START_NS + 3 * 3600 * 10 ** 9        # after every other test's stamps
    first = {}
    for topic, _, raw in BagPlayer(client.node, bag).messages():
        first.setdefault(topic, raw)
    image = deserialize_message(first[topics.IMAGE_TOPIC], Image)
    info = deserialize_message(first[topics.CAMERA_INFO_TOPIC], CameraInfo)
    tf = deserialize_message(first[topics.TF_TOPIC], TFMessage)
    for header in [image.header, info.header, *(t.header for t in tf.transforms)]:
        header.stamp.sec, header.stamp.nanosec = divmod(stamp, 10 ** 9)
    log.mark()
    client.image.publish(image)
    client.info.publish(info)
    assert client.spin_until(lambda: any(stamp_to_ns(m.markers[0].header.stamp) == stamp
                                         for m in client.received[MARKERS])), log.path
    client.spin_until(lambda: False, timeout_s=0.3)     # answered; TF is still to come
    assert map_at(client, stamp) is None
    client.tf.publish(tf)
    assert client.spin_until(lambda: map_at(client, stamp) is not None), log.path
    assert map_at(client, stamp).detections
    assert not log.wait_for('WARN', 'no camera pose for the map', timeout_s=0.5)
