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
bbpose_node in this process: a run-time rebuild does not stop it serving, stamps reset tracks.

The node spins on its own executor thread; a client in another context talks to it over
DDS as any other node would. A rebuild is held at a gate the test opens, so that frames
are sent and answered while it is known to be running.
"""

import threading

import pytest
from rcl_interfaces.srv import SetParameters
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from sensor_msgs.msg import CameraInfo, Image
from test_ros_support import GraphClient, TIMEOUT_S, use_private_domain, weight_files
from visualization_msgs.msg import Marker, MarkerArray

from bbpose_ros.bags import topics
from bbpose_ros.cli.graph.graph_bench import camera_messages
from bbpose_ros.core.data.stamps import stamp_to_ns
from bbpose_ros.core.pipeline.tracking import PoseTracker
from bbpose_ros.ros import node as node_module

pytestmark = pytest.mark.slow   # starts bbpose_node as a process

OUT = '/bbpose_node'
MARKERS = f'{OUT}/markers'


@pytest.fixture(scope='module')
def served(lmo, lmo_root, tmp_path_factory):
    """Start the node (ape only, tracking on) in this process and a client; stop both."""
    use_private_domain(offset=8)
    weights = weight_files(tmp_path_factory.mktemp('weights'))
    context = Context()
    rclpy.init(context=context)
    remaps = ['--ros-args', '-r', f'image:={topics.IMAGE_TOPIC}',
              '-r', f'camera_info:={topics.CAMERA_INFO_TOPIC}']
    node = node_module.BBPoseNode(context=context, cli_args=remaps, parameter_overrides=[
        Parameter('dataset_dir', value=str(lmo_root)),
        Parameter('detector_weights', value=str(weights[0])),
        Parameter('qnet_weights', value=str(weights[1])),
        Parameter('objects', value=['ape']), Parameter('score_threshold', value=0.0),
        Parameter('tracking', value=True)])
    assert node.trigger_configure() == node_module.SUCCESS, node.failure
    assert node.trigger_activate() == node_module.SUCCESS, node.failure
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    spinning = threading.Thread(target=executor.spin, daemon=True)
    spinning.start()
    client = GraphClient()
    client.image = client.publisher(Image, topics.IMAGE_TOPIC)
    client.info = client.publisher(CameraInfo, topics.CAMERA_INFO_TOPIC)
    client.subscribe(MarkerArray, MARKERS)
    client.pair = camera_messages(lmo.frames()[:1])[0]
    assert client.spin_until(lambda: client.image.get_subscription_count() > 0
                             and client.info.get_subscription_count() > 0
                             and client.node.count_publishers(MARKERS) > 0)
    yield node, client
    client.close()
    executor.shutdown()
    node.destroy_node()
    rclpy.try_shutdown(context=context)
    spinning.join(TIMEOUT_S)


def answer(client, stamp_ms):
    """Publish the frame stamped ``stamp_ms`` milliseconds; return its MarkerArray (or None)."""
    image, info = client.pair
    for message in (image, info):
        message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp_ms * 10 ** 6,
                                                                        10 ** 9)
    client.image.publish(image)
    client.info.publish(info)

    def received():
        return next((m for m in client.received[MARKERS]
                     if stamp_to_ns(m.markers[0].header.stamp) == stamp_ms * 10 ** 6), None)
    client.spin_until(lambda: received() is not None)
    return received()


def reported(markers):
    """Return the object names of a MarkerArray's boxes."""
    return {m.ns for m in markers.markers if m.type == Marker.LINE_LIST}


def set_parameter(client, name, value):
    """Set one node parameter through its service; returns whether the set was taken."""
    request = SetParameters.Request(parameters=[Parameter(name, value=value).to_parameter_msg()])
    response = client.call(SetParameters, f'{OUT}/set_parameters', request)
    return response is not None and response.results[0].successful


def test_frames_are_answered_while_a_rebuild_runs(served, monkeypatch):
    node, client = served
    gate, building = threading.Event(), threading.Event()
    build = node_module.build_node_pipeline

    def held_build(config, log=None):
        building.set()
        assert gate.wait(TIMEOUT_S)
        return build(config, log)

    monkeypatch.setattr(node_module, 'build_node_pipeline', held_build)
    assert reported(answer(client, 1_000_000)) == {'ape'}     # score 0: always reported
    assert set_parameter(client, 'objects', ['can'])      # answered before the build ends
    assert building.wait(TIMEOUT_S)
    # The rebuild is held: these frames go through the pipeline the node had.
    for stamp_ms in (1_001_000, 1_002_000):
        markers = answer(client, stamp_ms)
        assert markers is not None and reported(markers) == {'ape'}
    assert node.config.objects == ('ape',)
    gate.set()
    assert client.spin_until(lambda: node.config.objects == ('can',))
    assert reported(answer(client, 1_003_000)) == {'can'}


def test_a_backward_stamp_jump_resets_the_tracks(served, monkeypatch):
    node, client = served
    tracker = node.pipeline.pipeline
    assert isinstance(tracker, PoseTracker)
    resets = []
    reset = tracker.reset
    monkeypatch.setattr(tracker, 'reset', lambda: resets.append(1) or reset())
    for stamp_ms in (2_000_000, 2_001_000):
        assert answer(client, stamp_ms) is not None
    assert resets == []                                   # forward in time: no reset
    assert answer(client, 1_500_000) is not None               # a bag restarted
    assert resets == [1]
    assert answer(client, 1_501_000) is not None               # the new stream goes on
    assert resets == [1]


def test_stream_mode_job_ends_with_deactivate(served):
    node, client = served
    assert set_parameter(client, 'tracking_redetect_every', 1)
    assert set_parameter(client, 'tracking_stream', True)
    assert client.spin_until(lambda: node.config.options.tracking_stream)
    tracker = node.pipeline.pipeline
    assert isinstance(tracker, PoseTracker)
    # A first frame is detected in the frame; the next, 5 ms later by the stamps (a camera
    # faster than the pipeline), is answered by the tracks and handed on.
    assert answer(client, 3_000_000) is not None and not tracker.background_running
    assert answer(client, 3_000_005) is not None
    assert tracker.background_running
    assert node.trigger_deactivate() == node_module.SUCCESS
    assert not tracker.background_running
    assert not [t for t in threading.enumerate() if t.name == 'bbpose_detection']
    assert node.trigger_activate() == node_module.SUCCESS
    assert answer(client, 3_001_000) is not None and answer(client, 3_001_005) is not None
    assert node.pipeline.pipeline is tracker and tracker.background_running
