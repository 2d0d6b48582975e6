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
Frames published at a fixed rate into a running ``bbpose_node``, as a camera would.

Unlike the lockstep replay of ``graph.replay``, each frame (an Image and a CameraInfo stamped
with the time of publication) goes out on time whether or not the node has answered the
previous one. A node slower than the rate must then drop frames (it keeps only the newest)
rather than queue them, so the latency of the frames it answers stays bounded. The node runs
as a child process with the shipped Fast DDS profile for large images, like
``bbpose replay-eval``.

Answers are timed with the reception time DDS gives each sample (``received_timestamp``,
system clock), not with when this process's executor got round to its callback, so a busy
benchmark process does not inflate the latencies it reports.
"""

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
import time

from geometry_msgs.msg import PoseStamped
import rclpy
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import CameraInfo, Image
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import MarkerArray

from bbpose_ros.bags import topics
from bbpose_ros.bags.player import PLAY_QOS
from bbpose_ros.bags.typestore import TYPESTORE
from bbpose_ros.bags.writer import camera_info_message, image_message
from bbpose_ros.cli.graph.replay import DIAGNOSTICS_TIMEOUT_S, NodeProcess, Recorder
from bbpose_ros.cli.graph.replay import use_large_image_profile
from bbpose_ros.core.data.bop import BopFrame
from bbpose_ros.core.data.stamps import stamp_to_ns
from bbpose_ros.core.eval.benchmark import sample_process
from bbpose_ros.core.eval.recorded_poses import Recording
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.ros.params import NODE_NAME

WARMUP_FRAMES = 5          # answered one by one before the clock starts
START_TIMEOUT_S = 120.0    # node start (torch, meshes, weights) and DDS matching
ANSWER_TIMEOUT_S = 30.0    # per warm-up frame
DRAIN_S = 2.0              # after the last frame, for its answer


def camera_messages(frames: Iterable[BopFrame]) -> list[tuple[Image, CameraInfo]]:
    """Make (Image, CameraInfo) rclpy messages of BopFrames, as ``bbpose make-bag`` writes them."""
    return [(_to_rclpy(image_message(0, topics.DEFAULT_FRAME_ID, frame.load_image()),
                       topics.IMAGE_TYPE, Image),
             _to_rclpy(camera_info_message(0, topics.DEFAULT_FRAME_ID, frame.camera),
                       topics.CAMERA_INFO_TYPE, CameraInfo))
            for frame in frames]


def camera_transforms(frames: Iterable[BopFrame]) -> list[TFMessage | None]:
    """
    Make each BopFrame's /tf message of its camera pose (world -> camera), as make-bag does.

    None for a frame without a camera pose; the publisher restamps them with the images.
    """
    def message(pose):
        return _to_rclpy(topics.transform_message(0, topics.FIXED_FRAME,
                                                  topics.DEFAULT_FRAME_ID, pose),
                         topics.TF_TYPE, TFMessage)
    return [None if frame.world_from_camera is None else message(frame.world_from_camera)
            for frame in frames]


def _to_rclpy(message, msgtype, cls):
    """Turn a rosbags message into the rclpy message of class ``cls`` through its CDR bytes."""
    return deserialize_message(bytes(TYPESTORE.serialize_cdr(message, msgtype)), cls)


class CameraPublisher:
    """
    Publishes prepared (Image, CameraInfo) pairs on the camera topics, restamped.

    Args:
        node: the rclpy Node that owns the publishers.
        pairs: list of (Image, CameraInfo), used in turn.
        transforms: per pair, its camera's /tf message (``camera_transforms``) or None.

    """

    def __init__(self, node: Node, pairs: Sequence[tuple[Image, CameraInfo]],
                 transforms: Sequence[TFMessage | None] = ()) -> None:
        self.pairs = pairs
        self.transforms = transforms
        self.image = node.create_publisher(Image, topics.IMAGE_TOPIC, PLAY_QOS)
        self.info = node.create_publisher(CameraInfo, topics.CAMERA_INFO_TOPIC, PLAY_QOS)
        self.tf = node.create_publisher(TFMessage, topics.TF_TOPIC, 100) if any(
            t is not None for t in transforms) else None

    def publish(self, index: int, stamp_ns: int) -> None:
        """Publish pair ``index`` (modulo their number), its camera's TF first, stamped."""
        image, info = self.pairs[index % len(self.pairs)]
        transform = self.transforms[index % len(self.pairs)] if self.tf is not None else None
        headers = [image.header, info.header] + ([] if transform is None else
                                                 [transform.transforms[0].header])
        for header in headers:
            header.stamp.sec, header.stamp.nanosec = divmod(stamp_ns, 10 ** 9)
        if transform is not None:
            self.tf.publish(transform)
        self.image.publish(image)
        self.info.publish(info)


class ArrivalClock:
    """
    When the node's answers arrived, by image stamp, in system-clock seconds.

    Fills a Recording: ``pose_received_s`` (the frame's last PoseStamped) and ``answered_s``
    (its MarkerArray), from each sample's DDS reception time; the caller fills
    ``published_s`` with time.time_ns() * 1e-9 at publication.

    Args:
        node: the rclpy Node that owns the subscriptions.
        objects: object names whose ``/<node>/<object>/pose`` topics are timed.

    """

    def __init__(self, node: Node, objects: Iterable[str]) -> None:
        self.recording = Recording()
        for name in objects:
            node.create_subscription(PoseStamped, f'/{NODE_NAME}/{name}/pose', self._on_pose,
                                     PLAY_QOS.depth * 10)
        node.create_subscription(MarkerArray, f'/{NODE_NAME}/markers', self._on_markers,
                                 PLAY_QOS.depth * 10)

    def _on_pose(self, message, info):
        stamp, arrived_s = stamp_to_ns(message.header.stamp), _received_s(info)
        received = self.recording.pose_received_s
        received[stamp] = max(received.get(stamp, arrived_s), arrived_s)

    def _on_markers(self, message, info):
        if message.markers:
            self.recording.answered_s.setdefault(stamp_to_ns(message.markers[0].header.stamp),
                                                 _received_s(info))


def _received_s(info):
    """System-clock seconds at which DDS received a sample (rclpy MessageInfo)."""
    return info['received_timestamp'] * 1e-9


@dataclass(frozen=True)
class GraphRun:
    """
    What one fixed-rate run measured.

    Attributes:
        recording: the Recording of the timed frames: publication and answer times in
            system-clock seconds (see ArrivalClock).
        node_start, node_end: ProcessSamples of the node when the first and the last frame
            were published.
        node_counts: {counter: frames} the node counted during the run (see diagnostics).
        node_rss_trace: [(seconds since the first publication, node RSS in MB)], about one
            a second.
        stop_s: seconds from SIGINT to the node's exit, after the run.
        exit_code: the node's exit code.

    """

    recording: Recording
    node_start: object
    node_end: object
    node_counts: dict
    node_rss_trace: list
    stop_s: float | None = None
    exit_code: int | None = None


def run_graph(pairs: Sequence[tuple[Image, CameraInfo]], objects: Iterable[str],
              params_file: Path | str, overrides: Sequence[str], rate_hz: float,
              duration_s: float, transforms: Sequence[TFMessage | None] = ()) -> GraphRun:
    """
    Start the node, warm it up, publish at ``rate_hz`` for ``duration_s`` and stop it.

    Args:
        pairs: (Image, CameraInfo) messages to publish in turn (``camera_messages``).
        objects: object names whose pose topics are recorded.
        params_file, overrides: the node's parameters file and ``name:=value`` overrides.
        rate_hz: frames per second.
        duration_s: length of the timed run in seconds.
        transforms: per pair, the /tf message of its camera pose, or None
            (``camera_transforms``; a node with ``fixed_frame`` maps with them).

    Returns:
        A GraphRun.

    """
    use_large_image_profile()
    rclpy.init(args=[], signal_handler_options=SignalHandlerOptions.NO)
    node = Node('bbpose_bench')
    process = NodeProcess(params_file, overrides)
    try:
        camera = CameraPublisher(node, pairs, transforms)
        recorder = Recorder(node, ())      # connection, warm-up answers and diagnostics
        clock = ArrivalClock(node, objects)
        baseline = _warm_up(camera, recorder, process)
        run = _timed_run(camera, recorder, clock, process, baseline, rate_hz, duration_s)
    finally:
        stopping = time.perf_counter()
        code = process.stop()
        stop_s = time.perf_counter() - stopping
        node.destroy_node()
        rclpy.try_shutdown()
    return replace(run, stop_s=stop_s, exit_code=code)


def _warm_up(camera, recorder, process):
    """Connect, have WARMUP_FRAMES answered one by one; return the node's counters then."""
    if not recorder.spin_until(lambda: recorder.connected([camera.image, camera.info]),
                               START_TIMEOUT_S, process):
        raise InputError(f'the node did not connect within {START_TIMEOUT_S} s')
    recording = recorder.recording
    for index in range(WARMUP_FRAMES):
        stamp = time.time_ns()
        camera.publish(index, stamp)
        if not recorder.spin_until(lambda: stamp in recording.answered_s, ANSWER_TIMEOUT_S,
                                   process):
            raise InputError(f'the node did not answer a warm-up frame in {ANSWER_TIMEOUT_S} s')
    recorder.spin_until(lambda: recording.counts.get('answered', 0) >= WARMUP_FRAMES,
                        DIAGNOSTICS_TIMEOUT_S, process)
    return dict(recording.counts)


def _timed_run(camera, recorder, clock, process, baseline, rate_hz, duration_s):
    """Publish on a fixed clock, then wait for the last answer and the node's counters."""
    recording = clock.recording = Recording()
    diagnostics = recorder.recording = Recording()
    period_s = 1.0 / rate_hz
    start = sample_process(process.process.pid)
    begin_s = time.perf_counter()
    rss_trace = []
    for index in range(max(1, round(duration_s * rate_hz))):
        if index % max(1, round(rate_hz)) == 0:
            rss_trace.append((time.perf_counter() - begin_s,
                              sample_process(process.process.pid).rss_mb))
        due_s = begin_s + index * period_s
        while (left_s := due_s - time.perf_counter()) > 0:
            recorder.executor.spin_once(timeout_sec=left_s)
        process.check_alive()
        stamp_ns = time.time_ns()
        recording.published_s[stamp_ns] = stamp_ns * 1e-9
        camera.publish(index, stamp_ns)
    end = sample_process(process.process.pid)
    recorder.spin_until(lambda: stamp_ns in recording.answered_s, DRAIN_S, process)
    answered = baseline.get('answered', 0) + len(recording.answered_s)
    recorder.spin_until(lambda: diagnostics.counts.get('answered', -1) >= answered,
                        DIAGNOSTICS_TIMEOUT_S, process)
    recording.timings_ms = diagnostics.timings_ms
    counts = {key: value - baseline.get(key, 0) for key, value in diagnostics.counts.items()}
    return GraphRun(recording, start, end, counts, rss_trace)
