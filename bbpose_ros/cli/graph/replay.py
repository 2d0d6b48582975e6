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
Replay a bag through a running ``bbpose_node`` and record what it answers.

Frames are played in lockstep (``replay_bag``): each image (with the messages that follow
it in the bag) is published once the node has answered the previous one, so a node slower
than the bag's rate still answers every frame; or paced: each message at its recorded time,
as a camera streams, the node dropping what it cannot keep up with. A frame counts as
answered when its MarkerArray arrives (the node publishes one per processed frame, after
the frame's poses).
"""

from collections.abc import Callable, Iterable, MutableMapping, Sequence
import math
import os
from pathlib import Path
import signal
import subprocess
import sys
import time
from typing import IO

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.serialization import deserialize_message
from tf2_msgs.msg import TFMessage
from vision_msgs.msg import Detection3DArray
from visualization_msgs.msg import MarkerArray

from bbpose_ros.bags import topics
from bbpose_ros.bags.player import BagPlayer
from bbpose_ros.core.data.stamps import stamp_to_ns
from bbpose_ros.core.eval.recorded_poses import Recording
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.ros.diagnostics import counts_from_status, timings_from_status
from bbpose_ros.ros.params import NODE_NAME
from bbpose_ros.ros.params_file import package_config_file

DEFAULT_PARAMS = package_config_file('bbpose.yaml')   # the node's parameters file
FASTDDS_PROFILE = package_config_file('fastdds_large_images.xml')
FASTDDS_ENV = 'FASTRTPS_DEFAULT_PROFILES_FILE'
STOP_TIMEOUT_S = 5.0
DIAGNOSTICS_TIMEOUT_S = 3.0   # the node publishes them at 1 Hz
POLL_S = 0.02


def use_large_image_profile(environ: MutableMapping[str, str] = os.environ) -> None:
    """Select the shipped Fast DDS profile for large images unless one is already set."""
    if FASTDDS_PROFILE.is_file() and not environ.get(FASTDDS_ENV):
        environ[FASTDDS_ENV] = str(FASTDDS_PROFILE)


class NodeProcess:
    """
    ``bbpose_node`` as a child process, with its inputs remapped to the bag's topics.

    Args:
        params_file: ROS 2 parameters file.
        overrides: extra ``name:=value`` parameters.
        image_topic, camera_info_topic: topics the node subscribes to.
        stderr: where its log goes (subprocess.Popen's stderr; None: this process's).

    """

    def __init__(self, params_file: Path | str, overrides: Sequence[str] = (),
                 image_topic: str = topics.IMAGE_TOPIC,
                 camera_info_topic: str = topics.CAMERA_INFO_TOPIC,
                 stderr: int | IO | None = None) -> None:
        command = [sys.executable, '-m', 'bbpose_ros.ros.node', '--ros-args',
                   '--params-file', str(params_file)]
        for override in overrides:
            command += ['-p', override]
        command += ['-r', f'image:={image_topic}', '-r', f'camera_info:={camera_info_topic}']
        self.process = subprocess.Popen(command, stderr=stderr)

    def check_alive(self) -> None:
        """Raise InputError when the node has exited (its log is on stderr)."""
        code = self.process.poll()
        if code is not None:
            raise InputError(f'{NODE_NAME} exited with code {code}; see its log above')

    def stop(self) -> int:
        """SIGINT, then SIGKILL after STOP_TIMEOUT_S; returns the exit code."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                self.process.kill()
        return self.process.wait()


class Recorder:
    """
    Subscribes to the node's outputs and fills a Recording.

    Args:
        node: the rclpy Node that owns the subscriptions.
        objects: object names whose ``/<node>/<object>/pose`` topics are recorded; also
            ``/<node>/detections``, ``/<node>/markers``, ``/tf`` and ``/diagnostics``.
        scene_map: also record ``/<node>/map/detections`` (a node with ``fixed_frame``).

    """

    def __init__(self, node: Node, objects: Iterable[str], scene_map: bool = False) -> None:
        self.node = node
        self.recording = Recording()
        self.executor = SingleThreadedExecutor(context=node.context)
        self.executor.add_node(node)
        self.markers_topic = f'/{NODE_NAME}/markers'
        self.topics = {f'/{NODE_NAME}/{name}/pose': (PoseStamped, self._on_pose, name)
                       for name in objects}
        self.topics[self.markers_topic] = (MarkerArray, self._on_markers, None)
        self.topics[f'/{NODE_NAME}/detections'] = (Detection3DArray, self._on_detections, None)
        self.topics['/tf'] = (TFMessage, self._on_tf, None)
        self.topics['/diagnostics'] = (DiagnosticArray, self._on_diagnostics, None)
        if scene_map:
            self.topics[f'/{NODE_NAME}/map/detections'] = (Detection3DArray, self._on_map, None)
        for topic, (cls, handler, name) in self.topics.items():
            node.create_subscription(cls, topic, self._callback(topic, cls, handler, name), 100,
                                     raw=True)

    def spin_until(self, done: Callable[[], bool], timeout_s: float,
                   process: NodeProcess | None = None, latest: float | None = None) -> bool:
        """
        Spin until ``done()`` is true; returns False on timeout or raises if process died.

        ``latest``: a ``time.monotonic()`` by which ``done()`` is expected true, so that
        no wait for messages outlasts it (a paced replay's next message).
        """
        deadline = time.monotonic() + timeout_s
        while not done():
            now = time.monotonic()
            if now > deadline:
                return False
            if process is not None:
                process.check_alive()
            wait = POLL_S if latest is None else min(POLL_S, max(latest - now, 0.0))
            self.executor.spin_once(timeout_sec=wait)
        return True

    def connected(self, publishers: Iterable[Publisher]) -> bool:
        """Return True when ``publishers`` all have subscribers and every output a publisher."""
        return all(p.get_subscription_count() > 0 for p in publishers) and \
            all(self.node.count_publishers(topic) > 0 for topic in self.topics
                if topic != '/diagnostics')

    def _callback(self, topic, cls, handler, name):
        msgtype = f'{cls.__module__.split(".")[0]}/msg/{cls.__name__}'

        def callback(raw):
            self.recording.messages.append((topic, msgtype, time.time_ns(), raw))
            handler(deserialize_message(raw, cls), name)
        return callback

    def _on_pose(self, message, name):
        stamp = stamp_to_ns(message.header.stamp)
        rotation, translation = topics.pose_from_message(message)
        self.recording.poses.setdefault(stamp, []).append((name, rotation, translation))
        self.recording.pose_received_s[stamp] = time.perf_counter()

    def _on_detections(self, message, _):
        self.recording.detections[stamp_to_ns(message.header.stamp)] = [
            (detection.results[0].hypothesis.class_id,
             *topics.pose_from_message(detection.results[0].pose))
            for detection in message.detections]

    def _on_map(self, message, _):
        self.recording.map_detections[stamp_to_ns(message.header.stamp)] = [
            (detection.results[0].hypothesis.class_id,
             *topics.pose_from_message(detection.results[0].pose))
            for detection in message.detections]

    def _on_tf(self, message, _):
        for transform in message.transforms:
            stamp = stamp_to_ns(transform.header.stamp)
            self.recording.transforms[stamp] = self.recording.transforms.get(stamp, 0) + 1

    def _on_markers(self, message, _):
        if message.markers:
            stamp = stamp_to_ns(message.markers[0].header.stamp)
            self.recording.answered_s.setdefault(stamp, time.perf_counter())

    def _on_diagnostics(self, message, _):
        for status in message.status:
            if status.name.startswith(f'{NODE_NAME}:'):
                self.recording.timings_ms = timings_from_status(status)
                self.recording.counts = counts_from_status(status)


def replay_bag(player: BagPlayer, recorder: Recorder, process: NodeProcess,
               paced: bool = False, image_topic: str = topics.IMAGE_TOPIC,
               start_timeout_s: float = 120.0, answer_timeout_s: float = 30.0,
               progress: Callable[[int], object] | None = None,
               before_image: Callable[[int], object] | None = None) -> Recording:
    """
    Play every message of the bag into the node; return the Recording.

    In lock step each image (with the messages that follow it in the bag) is published once
    the node answered the previous one (a frame left unanswered within
    ``answer_timeout_s`` is counted, not retried). ``paced``: each message at its recorded
    time, as the camera sent it; no frame waits for an answer, and a node slower than the
    bag's rate drops frames (they stay unanswered). Either way the last frame's answer is
    waited for up to ``answer_timeout_s``. Waits up to ``start_timeout_s`` for the node to
    connect; ``progress`` is called with the number of images sent. ``image_topic`` holds
    the frames (sensor_msgs/Image, or CompressedImage for a node with ``image_transport``
    compressed). ``before_image`` is called with each image's stamp before it is sent
    (``replay-eval`` clears the node's map there where a new scene begins).
    """
    recording = recorder.recording
    inputs = [publisher for topic, publisher in player.publishers.items()
              if topic in (image_topic, topics.CAMERA_INFO_TOPIC)]
    if not recorder.spin_until(lambda: recorder.connected(inputs), start_timeout_s, process):
        raise InputError(f'{NODE_NAME} did not connect within {start_timeout_s} s')
    first = start = last = None
    for topic, recorded_ns, raw in player.messages():
        if paced:
            if first is None:
                first, start = recorded_ns, time.monotonic()
            due = start + (recorded_ns - first) * 1e-9
            recorder.spin_until(lambda: time.monotonic() >= due, math.inf, process,
                                latest=due)
            recorder.executor.spin_once(timeout_sec=0.0)    # answers, also when late
        if topic == image_topic:
            if not paced:
                _wait_answer(recorder, last, answer_timeout_s, process)
            last = stamp_to_ns(deserialize_message(raw, player.types[topic]).header.stamp)
            if before_image is not None:
                before_image(last)
            recording.published_s[last] = time.perf_counter()
            if progress is not None:
                progress(len(recording.published_s))
        player.publish(topic, raw)
    _wait_answer(recorder, last, answer_timeout_s, process)
    answered = len(recording.answered_s)
    recorder.spin_until(lambda: recording.counts.get('answered', -1) >= answered,
                        DIAGNOSTICS_TIMEOUT_S, process)
    return recording


def _wait_answer(recorder, stamp, timeout_s, process):
    if stamp is not None:
        recorder.spin_until(lambda: stamp in recorder.recording.answered_s, timeout_s, process)
