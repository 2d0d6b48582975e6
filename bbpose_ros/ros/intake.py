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
Frame intake: the ``image`` and ``camera_info`` subscriptions, their checks and pairing.

The callbacks run on the executor thread and only check, decode and pair: an image's stamp
(``core/data/stamps.py``: repeated, gone back, from the future), its frame_id, its encoding
and size; a CameraInfo when it pairs (``camera_model``). Each problem is counted for
/diagnostics and logged, throttled; a bad image or CameraInfo drops the frame, the others
are answered anyway. Images wait a while for their CameraInfo (``pairing.StampPairer``);
each pair goes to ``hand_off`` (the worker) as a Frame and its CameraModel.

With ``image_transport: compressed`` the image subscription is image_transport's: a
sensor_msgs/CompressedImage on the resolved ``image`` topic + ``/compressed``. Its callback
checks the header only; the pair goes to the worker as the undecoded Frame and its
CameraInfo, and the worker calls ``decode`` (JPEG or PNG, then the CameraModel) for the one
frame it takes, so frames that a newer one replaces are never decoded.
"""

from collections.abc import Callable
from dataclasses import replace
import re
import time

from rclpy.event_handler import QoSRequestedIncompatibleQoSInfo, SubscriptionEventCallbacks
from rclpy.lifecycle import LifecycleNode
from rclpy.qos import QoSPolicyKind, QoSProfile
from rclpy.subscription import Subscription
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from std_msgs.msg import Header

from bbpose_ros.core.data.compressed_image import decode_compressed
from bbpose_ros.core.data.stamps import BACKWARDS, REPEATED, stamp_to_ns, StampChecker
from bbpose_ros.core.geometry import camera_info
from bbpose_ros.core.geometry.camera_info import CameraModel
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.ros import conversions
from bbpose_ros.ros.diagnostics import incompatible_qos_text, InputWatch, NodeStats
from bbpose_ros.ros.frame import Frame, stamp_text
from bbpose_ros.ros.pairing import Pairing, StampPairer
from bbpose_ros.ros.throttle import ProblemLog

# An image waiting longer for its CameraInfo is dropped. Longer than a reliable writer's
# repair of a lost sample (Fast DDS heartbeat period: 3 s), which a burst of large images
# can make a CameraInfo wait for; a newer image that pairs drops the older waiting ones.
UNPAIRED_TIMEOUT_S = 5.0
# While serving, no image for this long is a WARN condition in /diagnostics (a publisher
# with an incompatible QoS, a remap to the wrong topic, a camera that stopped).
STALE_INPUT_S = 3.0
# How far ahead of this node's clock an image stamp may be before it is reported: clocks of
# synchronised machines agree much better, a camera on its own clock is far off.
FUTURE_STAMP_TOLERANCE_NS = 1_000_000_000
# image_transport's topic suffix of its compressed transport.
COMPRESSED_SUFFIX = '/compressed'


class FrameIntake:
    """
    The input side of the node: subscriptions made by activate, destroyed by deactivate.

    Args:
        node: the node they belong to; its ``max_image_pixels``, ``rectified``,
            ``sync_slop`` and ``qos_reliability`` parameters are read as frames come.
        stats: the frame counters (``received``).
        problems: counts and logs what is wrong with an input.
        hand_off: takes each (Frame, CameraModel) pair; a compressed Frame comes with its
            CameraInfo instead, for ``decode``.

    """

    def __init__(self, node: LifecycleNode, stats: NodeStats, problems: ProblemLog,
                 hand_off: Callable[[Frame, CameraModel | CameraInfo], None]) -> None:
        self._node = node
        self._stats = stats
        self._problems = problems
        self._hand_off = hand_off
        self._watch = InputWatch(STALE_INPUT_S)
        self._subscriptions: list[Subscription] = []
        self._pairer = StampPairer()
        self._stamps = StampChecker(FUTURE_STAMP_TOLERANCE_NS)
        self._stream = 0                          # backward stamp jumps seen
        self._index = 0                           # images of the stream received so far
        self._frame_ids_warned: set[tuple[str, str]] = set()
        self._transport = 'raw'

    @property
    def stream(self) -> int:
        """Return the number of backward stamp jumps seen: the stream of the next frame."""
        return self._stream

    def subscribe(self, qos: QoSProfile, transport: str = 'raw') -> None:
        """
        Take frames (activate): no image waits, no stamp is known; start the watch.

        ``transport`` is image_transport's name: 'raw' (Image on ``image``) or
        'compressed' (CompressedImage on the resolved ``image`` + COMPRESSED_SUFFIX).
        """
        self._pairer = StampPairer()
        self._stamps = StampChecker(FUTURE_STAMP_TOLERANCE_NS)
        self._frame_ids_warned = set()
        self._transport = transport
        self._watch.start()
        if transport == 'compressed':      # the resolved name: a remap applies to 'image'
            image = (CompressedImage, self.image_topic, self._on_compressed)
        else:
            image = (Image, 'image', self._on_image)
        self._subscriptions = [
            self._node.create_subscription(cls, topic, callback, qos,
                                           event_callbacks=self._input_events(self.topic(topic)))
            for cls, topic, callback in (image,
                                         (CameraInfo, 'camera_info', self._on_camera_info))]

    def unsubscribe(self) -> None:
        """Stop taking frames (deactivate)."""
        for subscription in self._subscriptions:
            self._node.destroy_subscription(subscription)
        self._subscriptions = []
        self._watch.stop()

    def expire(self) -> None:
        """Drop the images that waited longer than UNPAIRED_TIMEOUT_S for a CameraInfo."""
        for frame in self._pairer.expire(UNPAIRED_TIMEOUT_S):
            self._drop_unpaired(frame, f'none came within {UNPAIRED_TIMEOUT_S} s')

    def conditions(self) -> list[str]:
        """Return the input conditions holding now (``InputWatch``), as texts."""
        return self._watch.conditions(self.image_topic)

    def topic(self, name: str) -> str:
        """Return the resolved name of input topic ``name`` (after remapping)."""
        return self._node.resolve_topic_name(name)

    @property
    def image_topic(self) -> str:
        """
        Return the topic images come on: ``image`` resolved, + /compressed if compressed.

        As image_transport names it: the base topic is remapped (``-r image:=...``), the
        transport's suffix added after.
        """
        suffix = COMPRESSED_SUFFIX if self._transport == 'compressed' else ''
        return self.topic('image') + suffix

    def decode(self, frame: Frame, info: CameraInfo) -> tuple[Frame, CameraModel] | None:
        """
        Decode a compressed Frame and make its CameraModel (in the worker thread).

        Returns the Frame with its pixels and the CameraModel of its CameraInfo; None when
        the frame is dropped: bad compressed data (``bad_image``, logged naming the topic
        and the reason) or a bad CameraInfo (``bad_camera_info``).
        """
        message = frame.compressed
        try:
            image_rgb = decode_compressed(message.format, message.data,
                                          self._node.get_parameter('max_image_pixels').value)
        except InputError as err:
            # One throttle key per kind of problem: the byte counts in the text vary.
            self._problems.drop('bad_image', re.sub(r'\d+', 'N', str(err)),
                                f'compressed image on {self.image_topic} dropped (stamp '
                                f'{stamp_text(frame.header)}): {err}')
            return None
        frame = replace(frame, image_rgb=image_rgb, compressed=None)
        camera_model = self._camera_model(frame, info)
        return None if camera_model is None else (frame, camera_model)

    def _input_events(self, topic: str) -> SubscriptionEventCallbacks:
        """Event callbacks of an input subscription (a resolved topic): incompatible QoS."""
        def on_incompatible_qos(event: QoSRequestedIncompatibleQoSInfo) -> None:
            text = incompatible_qos_text(
                topic, QoSPolicyKind(event.last_policy_kind).name.lower(),
                self._node.get_parameter('qos_reliability').value)
            self._watch.incompatible(text)
            for _ in range(max(1, event.total_count_change)):
                self._problems.warn('qos_incompatible', topic, text)
        return SubscriptionEventCallbacks(incompatible_qos=on_incompatible_qos)

    def _on_image(self, message: Image) -> None:
        received_s = time.perf_counter()
        header = message.header
        if not self._take_header(header):
            return
        try:
            frame = Frame(header, conversions.image_to_rgb(
                message, self._node.get_parameter('max_image_pixels').value), received_s,
                self._stream, self._index - 1)
        except InputError as err:
            self._problems.drop('bad_image', str(err),
                                f'image dropped (stamp {stamp_text(header)}): {err}')
            return
        self._take(self._pairer.add_image(stamp_to_ns(header.stamp), frame,
                                          self._sync_slop()))

    def _on_compressed(self, message: CompressedImage) -> None:
        """Take a compressed image undecoded: the worker decodes the one it takes."""
        received_s = time.perf_counter()
        if not self._take_header(message.header):
            return
        frame = Frame(message.header, None, received_s, self._stream, self._index - 1,
                      compressed=message)
        self._take(self._pairer.add_image(stamp_to_ns(message.header.stamp), frame,
                                          self._sync_slop()))

    def _take_header(self, header: Header) -> bool:
        """Count an image and check its stamp and frame_id; False: dropped (stamp repeated)."""
        self._stats.count('received')
        self._watch.image()
        odd = self._stamps.check(stamp_to_ns(header.stamp),
                                 self._node.get_clock().now().nanoseconds)
        if odd is not None and odd[0] == REPEATED:
            self._problems.warn(REPEATED, REPEATED,
                                f'image dropped (stamp {stamp_text(header)}): {odd[1]}')
            return False
        if odd is not None and odd[0] == BACKWARDS:
            self._stream += 1            # a new stream: what was tracked is of the old one
            self._index = 0
        self._index += 1
        if odd is not None:
            self._problems.warn(odd[0], odd[0], f'image (stamp {stamp_text(header)}) '
                                f'answered anyway: {odd[1]}')
        if not header.frame_id:
            self._problems.warn(
                'frame_id_empty', 'frame_id', f'image (stamp {stamp_text(header)}) answered '
                'anyway: header.frame_id is empty, so its poses name no frame (and no TF is '
                'published)')
        return True

    def _on_camera_info(self, message: CameraInfo) -> None:
        self._take(self._pairer.add_info(stamp_to_ns(message.header.stamp), message,
                                         self._sync_slop()))

    def _take(self, pairing: Pairing) -> None:
        """Drop the images the pairer gave up, then hand its pairs on."""
        for frame, reason in pairing.dropped:
            self._drop_unpaired(frame, reason)
        for frame, info in pairing.pairs:
            self._pair(frame, info)

    def _pair(self, frame: Frame, info: CameraInfo) -> None:
        """Make the CameraModel of a paired CameraInfo and hand the pair on (or drop it)."""
        self._check_frame_ids(frame.header, info.header)
        if frame.image_rgb is None:      # compressed: its size is known once decoded
            self._hand_off(frame, info)
            return
        camera_model = self._camera_model(frame, info)
        if camera_model is not None:
            self._hand_off(frame, camera_model)

    def _camera_model(self, frame: Frame, info: CameraInfo) -> CameraModel | None:
        """Return the CameraModel of a frame's CameraInfo; None: dropped, counted and logged."""
        height, width = frame.image_rgb.shape[:2]
        try:
            return camera_info.camera_model(
                info, width, height, self._node.get_parameter('rectified').value)
        except InputError as err:
            self._problems.drop('bad_camera_info', str(err),
                                f'image dropped (stamp {stamp_text(frame.header)}): {err}')
            return None

    def _check_frame_ids(self, image: Header, info: Header) -> None:
        """Count a pair whose frame_ids differ (usually a wrong remap); log each such pair once."""
        if image.frame_id == info.frame_id or not (image.frame_id and info.frame_id):
            return
        self._stats.count('frame_id_mismatch')
        if (image.frame_id, info.frame_id) not in self._frame_ids_warned:
            self._frame_ids_warned.add((image.frame_id, info.frame_id))
            self._node.get_logger().warning(
                f'image (stamp {stamp_text(image)}) answered anyway: header.frame_id '
                f'"{image.frame_id}" differs from its camera_info\'s "{info.frame_id}" (a '
                f'wrong remap?); the poses are given in "{image.frame_id}"')

    def _drop_unpaired(self, frame: Frame, reason: str) -> None:
        offset_s = self._pairer.nearest_offset_s(stamp_to_ns(frame.header.stamp))
        if offset_s is None:
            key, problem = 'none', f'no {self.topic("camera_info")} received yet'
        else:
            key, problem = 'offset', (
                f'no {self.topic("camera_info")} with a stamp within sync_slop = '
                f'{self._sync_slop()} s; the nearest differs by {offset_s:.3f} s')
        self._problems.warn('unpaired', key, f'image dropped (stamp {stamp_text(frame.header)}): '
                            f'{problem} ({reason})')

    def _sync_slop(self) -> float:
        return self._node.get_parameter('sync_slop').value
