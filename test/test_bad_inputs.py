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
The bad-input catalogue: each kind of input published between good frames into one node.

For every kind the node keeps running and answers the good frame after it; a bad kind gives
one log line naming the field (throttled: one per kind) and raises its counter in
/diagnostics; an accepted variant is answered. docs/reliability.md lists the kinds and what
the node does with each. The tests run in file order; the last one stops the node with
SIGTERM while it estimates.
"""

from collections.abc import Callable
from dataclasses import dataclass
import signal
import time

import cv2
from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, QoSReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import CameraInfo, Image
from test_camera_model import DISTORTIONS, redistortion_maps
from test_ros_support import GraphClient, NodeLog, REPO_ROOT, TIMEOUT_S, use_private_domain
from test_ros_support import weight_files, write_params
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import Marker, MarkerArray

from bbpose_ros.bags import topics
from bbpose_ros.cli.graph.graph_bench import camera_messages
from bbpose_ros.cli.graph.replay import NodeProcess
from bbpose_ros.core.data.stamps import stamp_to_ns
from bbpose_ros.ros.diagnostics import counts_from_status

pytestmark = pytest.mark.slow   # starts bbpose_node as a process

OUT = '/bbpose_node'
MARKERS = f'{OUT}/markers'
START_S = 1_700_000_000
SECOND = 1_000_000_000


@dataclass(frozen=True)
class Kind:
    """
    One kind of input.

    Attributes:
        spoil: changes a good (Image, CameraInfo) pair in place, or None (``send`` does all).
        answered: whether the node answers the spoiled frame itself.
        counter: the /diagnostics counter that goes up (None: none does).
        log: the level and words of its one log line (empty: it logs nothing).
        send: publishes the kind instead of the spoiled pair (client, image, info).
        same_poses: the answer's poses equal those of the unspoiled frame.

    """

    spoil: Callable | None
    answered: bool = False
    counter: str | None = None
    log: tuple[str, ...] = ()
    send: Callable | None = None
    same_poses: bool = False


def _pixels(image):
    return np.frombuffer(bytes(image.data), np.uint8).reshape(image.height, image.width, 3)


def _set_pixels(image, pixels, encoding):
    pixels = np.ascontiguousarray(pixels)
    image.height, image.width = pixels.shape[:2]
    image.step = pixels.shape[1] * (pixels.shape[2] if pixels.ndim == 3 else 1)
    image.encoding, image.data = encoding, pixels.tobytes()


def _encoding(name):
    def spoil(image, info):
        image.encoding = name
    return spoil


def _bgr8(image, info):
    _set_pixels(image, _pixels(image)[:, :, ::-1], 'bgr8')


def _mono8(image, info):
    _set_pixels(image, cv2.cvtColor(_pixels(image), cv2.COLOR_RGB2GRAY), 'mono8')


def _bayer_rggb8(image, info):
    rgb = _pixels(image)
    mosaic = rgb[:, :, 1].copy()                 # G on the other two sites
    mosaic[0::2, 0::2] = rgb[0::2, 0::2, 0]      # R
    mosaic[1::2, 1::2] = rgb[1::2, 1::2, 2]      # B
    _set_pixels(image, mosaic, 'bayer_rggb8')


def _padded_rows(image, info):
    rows = _pixels(image).reshape(image.height, -1)
    padded = np.zeros((image.height, rows.shape[1] + 64), np.uint8)
    padded[:, :rows.shape[1]] = rows
    image.step, image.data = padded.shape[1], padded.tobytes()


def _step_too_small(image, info):
    image.step -= 3


def _step_too_large(image, info):
    image.step *= 2


def _data_short(image, info):
    image.data = bytes(image.data)[:-image.step // 2]


def _zero_size(image, info):
    image.height = image.width = image.step = 0
    image.data = b''


def _odd_size(image, info):
    _set_pixels(image, _pixels(image)[:479, :639], 'rgb8')
    info.width, info.height = 639, 479


def _resized(image, info):
    _set_pixels(image, cv2.resize(_pixels(image), (320, 240), interpolation=cv2.INTER_AREA),
                'rgb8')


def _huge(image, info):
    image.height = image.width = image.step = 8192
    image.encoding, image.data = 'mono8', bytes(8192 * 8192)


def _k(change):
    def spoil(image, info):
        k = np.array(info.k, dtype=float)
        change(k)
        info.k = k.tolist()
    return spoil


def _p_differs(image, info):
    p = np.array(info.p, dtype=float)
    p[0] *= 1.1                        # fx 10 % off in P only
    info.p = p.tolist()


def _sizes_differ(image, info):
    info.width, info.height = 800, 800


def _distorted(name):
    """Re-distort the frame with a known D and say so in its CameraInfo."""
    def spoil(image, info):
        maps = redistortion_maps(name, np.array(info.k).reshape(3, 3))
        _set_pixels(image, cv2.remap(_pixels(image), *maps, cv2.INTER_LINEAR), 'rgb8')
        info.distortion_model, info.d = name, DISTORTIONS[name]
    return spoil


def _distortion(model, d):
    def spoil(image, info):
        info.distortion_model, info.d = model, d
    return spoil


def _binned(image, info):
    _set_pixels(image, cv2.resize(_pixels(image), (320, 240), interpolation=cv2.INTER_AREA),
                'rgb8')
    info.binning_x = info.binning_y = 2


def _roi(image, info):
    _set_pixels(image, _pixels(image)[60:420, 100:500], 'rgb8')
    info.roi.x_offset, info.roi.y_offset, info.roi.width, info.roi.height = 100, 60, 400, 360


def _stamp(offset_s):
    """Set the bad frame's stamp ``offset_s`` from the previous good frame's."""
    def spoil(image, info):
        stamp = stamp_to_ns(image.header.stamp) - SECOND + int(offset_s * SECOND)
        for message in (image, info):
            message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp, SECOND)
    return spoil


def _future(image, info):
    for message in (image, info):
        message.header.stamp.sec = int(time.time()) + 3600


def _empty_frame_id(image, info):
    image.header.frame_id = info.header.frame_id = ''


def _other_frame_id(image, info):
    info.header.frame_id = 'another_camera_optical_frame'


def _late_camera_info(client, image, info):
    """
    Publish the image, the next one 0.2 s later, then each CameraInfo 0.25 s after its image.

    Each CameraInfo comes after the next image (5 Hz, 0.25 s late): both images wait, and
    both are answered (the following one waited for here, before the next good frame: the
    node's keep-last-1 camera_info subscription would otherwise let that frame's CameraInfo
    replace this one's unread on a busy machine).
    """
    following = deserialize_message(serialize_message(image), Image)
    following_info = deserialize_message(serialize_message(info), CameraInfo)
    for message in (following, following_info):
        message.header.stamp.nanosec = 200_000_000
    for message, publisher, wait_s in ((image, client.image, 0.2),
                                       (following, client.image, 0.05),
                                       (info, client.info, 0.2),
                                       (following_info, client.info, 0.0)):
        publisher.publish(message)
        client.spin_until(lambda: False, timeout_s=wait_s)
    assert answer(client, stamp_to_ns(following.header.stamp)) is not None


def _no_camera_info(client, image, info):
    """Publish images without their CameraInfo for 5 s (5 Hz; stamps 0.04 s apart)."""
    for k in range(25):
        image.header.stamp.nanosec = k * 40_000_000
        client.image.publish(image)
        client.spin_until(lambda: False, timeout_s=0.2)


def _best_effort_publisher(client, image, info):
    qos = QoSProfile(depth=1, reliability=QoSReliabilityPolicy.BEST_EFFORT)
    client.best_effort = client.node.create_publisher(Image, topics.IMAGE_TOPIC, qos)
    client.best_effort.publish(image)


def _parameter(name, value):
    def send(client, image, info):
        request = SetParameters.Request(
            parameters=[Parameter(name, value=value).to_parameter_msg()])
        assert not client.call(SetParameters, f'{OUT}/set_parameters',
                               request).results[0].successful
    return send


KINDS = {
    'unknown encoding (yuv422)': Kind(_encoding('yuv422'), counter='bad_image',
                                      log=('ERROR', 'field encoding')),
    '16UC1 (a depth image)': Kind(_encoding('16UC1'), counter='bad_image',
                                  log=('ERROR', 'field encoding')),
    'bgr8': Kind(_bgr8, answered=True, same_poses=True),
    'mono8': Kind(_mono8, answered=True),
    'bayer_rggb8': Kind(_bayer_rggb8, answered=True),
    'rows padded (step > width x 3)': Kind(_padded_rows, answered=True, same_poses=True),
    'step too small': Kind(_step_too_small, counter='bad_image', log=('ERROR', 'field step')),
    'step too large for the data': Kind(_step_too_large, counter='bad_image',
                                        log=('ERROR', 'field data')),
    'data shorter than height x step': Kind(_data_short, counter='bad_image',
                                            log=('ERROR', 'field data')),
    'zero size': Kind(_zero_size, counter='bad_image', log=('ERROR', 'fields height, width')),
    'odd size (639 x 479)': Kind(_odd_size, answered=True),
    'resized stream (320 x 240, CameraInfo 640 x 480)': Kind(_resized, answered=True),
    '8k x 8k image': Kind(_huge, counter='bad_image',
                          log=('ERROR', '8192x8192', 'fields height, width')),
    'K all zeros': Kind(_k(lambda k: k.fill(0.0)), counter='bad_camera_info',
                        log=('ERROR', 'field k')),
    'K NaN': Kind(_k(lambda k: k.__setitem__(2, np.nan)), counter='bad_camera_info',
                  log=('ERROR', 'field k')),
    'K inf': Kind(_k(lambda k: k.__setitem__(4, np.inf)), counter='bad_camera_info',
                  log=('ERROR', 'field k')),
    'negative focal length': Kind(_k(lambda k: k.__setitem__(0, -k[0])),
                                  counter='bad_camera_info',
                                  log=('ERROR', 'field k', 'must be positive')),
    'P and K disagreeing': Kind(_p_differs, counter='bad_camera_info',
                                log=('ERROR', 'fields k and p')),
    'image and CameraInfo sizes disagreeing': Kind(_sizes_differ, counter='bad_camera_info',
                                                   log=('ERROR', 'fields width, height')),
    'plumb_bob distortion': Kind(_distorted('plumb_bob'), answered=True),
    'equidistant distortion': Kind(_distorted('equidistant'), answered=True),
    'unsupported distortion model (fov)': Kind(
        _distortion('fov', [0.1]), counter='bad_camera_info',
        log=('ERROR', 'field distortion_model "fov"')),
    'D of the wrong length for plumb_bob': Kind(
        _distortion('plumb_bob', [-0.2, 0.05, 0.0]), counter='bad_camera_info',
        log=('ERROR', 'field d holds 3 coefficients')),
    'binning 2 x 2': Kind(_binned, answered=True),
    'ROI (400 x 360 at 100, 60)': Kind(_roi, answered=True),
    'stamp out of order': Kind(_stamp(-0.5), answered=True, counter='stamp_backwards',
                               log=('WARN', 'header.stamp', 'older')),
    'stamp repeated': Kind(_stamp(0.0), counter='stamp_repeated',
                           log=('WARN', 'header.stamp repeats')),
    'stamp far in the future': Kind(_future, answered=True, counter='stamp_future',
                                    log=('WARN', 'header.stamp', 'ahead')),
    'empty frame_id': Kind(_empty_frame_id, answered=True, counter='frame_id_empty',
                           log=('WARN', 'header.frame_id')),
    'image and CameraInfo frame_ids differing': Kind(
        _other_frame_id, answered=True, counter='frame_id_mismatch',
        log=('WARN', 'differs from its camera_info', 'another_camera_optical_frame')),
    'CameraInfo 0.25 s late, after the next image': Kind(None, answered=True,
                                                         send=_late_camera_info),
    'CameraInfo stamp 0.5 s off': Kind(None, counter='unpaired',
                                       log=('WARN', 'sync_slop', 'differs by 0.500 s'),
                                       send=lambda client, image, info: (
                                           client.image.publish(image),
                                           client.info.publish(_restamped(info, 0.5)))),
    'no CameraInfo for 5 s': Kind(None, counter='unpaired', log=('WARN', 'camera_info'),
                                  send=_no_camera_info),
    'a best-effort publisher': Kind(None, counter='qos_incompatible',
                                    log=('WARN', 'qos_reliability', 'reliability policy'),
                                    send=_best_effort_publisher),
    'parameter of a wrong type at run time': Kind(
        None, counter='parameters_refused', log=('WARN', 'parameter score_threshold'),
        send=_parameter('score_threshold', 'high')),
    'unknown parameter name at run time': Kind(
        None, counter='parameters_refused', log=('WARN', 'parameter no_such_parameter'),
        send=_parameter('no_such_parameter', 1)),
    'parameter out of range at run time': Kind(
        None, counter='parameters_refused', log=('WARN', 'parameter max_instances'),
        send=_parameter('max_instances', 1000)),
}


def _restamped(info, offset_s):
    stamp = stamp_to_ns(info.header.stamp) + int(offset_s * SECOND)
    info.header.stamp.sec, info.header.stamp.nanosec = divmod(stamp, SECOND)
    return info


@pytest.fixture(scope='module')
def graph(lmo, lmo_root, tmp_path_factory):
    """Start the node and a client; stop both at the end (if the last test did not)."""
    use_private_domain(offset=7)
    folder = tmp_path_factory.mktemp('catalogue')
    log = NodeLog(folder / 'node.log')
    node = NodeProcess(write_params(folder / 'params.yaml', lmo_root, weight_files(folder)),
                       stderr=log.file)
    client = GraphClient()
    client.image = client.publisher(Image, topics.IMAGE_TOPIC)
    client.info = client.publisher(CameraInfo, topics.CAMERA_INFO_TOPIC)
    client.subscribe(MarkerArray, MARKERS)
    client.subscribe(TFMessage, '/tf')
    client.subscribe(DiagnosticArray, '/diagnostics')
    client.raw = [serialize_message(m) for m in camera_messages(lmo.frames()[:1])[0]]
    assert client.connected((client.image, client.info), MARKERS), log.path
    yield client, node, log
    client.close()
    node.stop()


def pair(client, stamp_s):
    """Return a fresh good (Image, CameraInfo), both stamped ``stamp_s`` seconds."""
    image, info = (deserialize_message(raw, cls)
                   for raw, cls in zip(client.raw, (Image, CameraInfo)))
    for message in (image, info):
        message.header.stamp.sec, message.header.stamp.nanosec = stamp_s, 0
    return image, info


def answer(client, stamp_ns, timeout_s=TIMEOUT_S):
    """Wait for the MarkerArray of ``stamp_ns``; returns it (None on timeout)."""
    def found():
        return next((m for m in client.received[MARKERS]
                     if stamp_to_ns(m.markers[0].header.stamp) == stamp_ns), None)
    client.spin_until(lambda: found() is not None, timeout_s)
    return found()


def good_frame_answered(client, stamp_s, attempts=4):
    """
    Publish good frames stamped from ``stamp_s`` on until one is answered; returns whether.

    A later attempt is for the transport, not the node: after a message of many megabytes
    the loopback's buffers overflow and DDS resends what was lost only after a while, when
    the image waiting for its CameraInfo may have been dropped (unpaired).
    """
    for attempt in range(attempts):
        image, info = pair(client, stamp_s)
        image.header.stamp.nanosec = info.header.stamp.nanosec = attempt * 100_000_000
        client.image.publish(image)
        client.info.publish(info)
        if answer(client, stamp_to_ns(image.header.stamp), timeout_s=15.0) is not None:
            return True
    return False


def marker_poses(markers):
    """Return {(ns, id): (position, orientation)} of a MarkerArray's boxes."""
    return {(m.ns, m.id): (m.pose.position, m.pose.orientation) for m in markers.markers
            if m.type == Marker.LINE_LIST}


def counts(client):
    """Return the counters of the next /diagnostics status."""
    client.received['/diagnostics'].clear()
    client.spin_until(lambda: client.received['/diagnostics'])
    return counts_from_status(client.received['/diagnostics'][-1].status[0])


def log_lines(log, words):
    """Return the node's log lines since the mark that hold all ``words``."""
    return [line for line in log.path.read_text()[log._offset:].splitlines()
            if all(word in line for word in words)]


@pytest.mark.parametrize('name', list(KINDS))
def test_bad_input_between_good_frames(graph, name):
    client, node, log = graph
    kind = KINDS[name]
    base_s = START_S + 100 * list(KINDS).index(name)
    before = counts(client)
    log.mark()
    good = pair(client, base_s)
    client.image.publish(good[0])
    client.info.publish(good[1])
    expected = answer(client, stamp_to_ns(good[0].header.stamp))
    assert expected is not None, log.path

    # The node keeps one message per topic: each step waits for the node to have taken
    # the previous one, or a newer message would replace it unread.
    image, info = pair(client, base_s + 1)
    if kind.spoil is not None:
        kind.spoil(image, info)
    if kind.send is not None:
        kind.send(client, image, info)
    else:
        client.image.publish(image)
        client.info.publish(info)
    if kind.answered:
        markers = answer(client, stamp_to_ns(image.header.stamp))
        assert markers is not None, log.path
        if kind.same_poses:
            assert marker_poses(markers) == marker_poses(expected)
    if kind.log:
        assert log.wait_for(*kind.log), log.path
    if kind.counter is not None:
        assert client.spin_until(lambda: counts(client)[kind.counter] > before[kind.counter])

    assert good_frame_answered(client, base_s + 2), log.path
    if kind.spoil is not None:     # each stamp answered at most once
        stamp = stamp_to_ns(image.header.stamp)
        expected_answers = int(kind.answered or stamp == stamp_to_ns(good[0].header.stamp))
        assert sum(stamp_to_ns(m.markers[0].header.stamp) == stamp
                   for m in client.received[MARKERS]) == expected_answers
    if kind.answered and kind.spoil is not None:   # a transform per pose, if it names a frame
        transforms = [t for m in client.received['/tf'] for t in m.transforms
                      if stamp_to_ns(t.header.stamp) == stamp_to_ns(image.header.stamp)]
        boxes = [m for m in markers.markers if m.type == Marker.LINE_LIST]
        assert len(transforms) == (len(boxes) if image.header.frame_id else 0)
    if kind.log:
        most = 2 if kind.send is _no_camera_info else 1      # 5 s of it: one throttle period
        assert 1 <= len(log_lines(log, kind.log)) <= most
    else:
        assert not log_lines(log, ('ERROR',)) and not log_lines(log, ('WARN',))
    node.check_alive()


def test_the_reliability_doc_lists_every_kind():
    text = (REPO_ROOT / 'docs' / 'reliability.md').read_text()
    assert [name for name in KINDS if f'| {name} |' not in text] == []


def test_sigterm_during_inference_exits_cleanly(graph):
    client, node, log = graph
    # Frames at ~100 Hz keep the worker busy: the signal comes while it estimates.
    for k in range(30):
        image, info = pair(client, START_S + 10_000 + k)
        client.image.publish(image)
        client.info.publish(info)
        client.spin_until(lambda: False, timeout_s=0.01)
        if k == 20:
            node.process.send_signal(signal.SIGTERM)
    assert node.process.wait(30) == 0
    assert 'Traceback' not in log.path.read_text()
