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
The camera's pose in the fixed frame, from ``/tf`` and ``/tf_static``, for the map.

tf2_ros's buffer and listener where tf2_ros is installed, else
``core.scene.transform_buffer.TransformBuffer`` fed by this module's own subscriptions
(the wheel venv has no tf2_ros), with tf2_ros's listener QoS. A transform the buffer
refuses (NaN, not a rotation, a second parent) is counted (``warnings_map_bad_transform``),
logged, and changes nothing.
"""

from __future__ import annotations

import threading

import numpy as np
from rclpy.lifecycle import LifecycleNode
from rclpy.qos import DurabilityPolicy, QoSProfile
from std_msgs.msg import Header
from tf2_msgs.msg import TFMessage

from bbpose_ros.core.data.stamps import stamp_to_ns
from bbpose_ros.core.geometry.rigid import transform_matrix
from bbpose_ros.core.scene.transform_buffer import TransformBuffer, TransformUnavailable
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.ros.throttle import ProblemLog

try:
    import tf2_ros
except ImportError:         # the wheel venv: TransformBuffer stands in
    tf2_ros = None

# tf2_ros's listener QoS: /tf reliable, keep last 100; /tf_static transient local too, so
# the static transforms sent before the node started arrive.
TF_LISTENER_QOS = QoSProfile(depth=100)
TF_STATIC_QOS = QoSProfile(depth=100, durability=DurabilityPolicy.TRANSIENT_LOCAL)


class CameraPoses:
    """
    TF listened to while active; the camera's pose looked up per image (module docstring).

    Args:
        node: the node the subscriptions belong to.
        problems: counts and logs the transforms the buffer refuses.

    """

    def __init__(self, node: LifecycleNode, problems: ProblemLog) -> None:
        self._node = node
        self._problems = problems
        self._lock = threading.Lock()   # the buffer: executor (TF in) vs lookups
        self._buffer: TransformBuffer | None = None
        self._tf2 = None                # (tf2_ros.Buffer, its TransformListener)
        self._subscriptions = []

    def listen(self) -> None:
        """Start listening to TF (activate), with tf2_ros where installed."""
        if tf2_ros is not None:
            buffer = tf2_ros.Buffer()
            self._tf2 = (buffer, tf2_ros.TransformListener(buffer, self._node))
            return
        with self._lock:
            self._buffer = TransformBuffer()
        self._subscriptions = [
            self._node.create_subscription(TFMessage, '/tf', self._on_tf, TF_LISTENER_QOS),
            self._node.create_subscription(TFMessage, '/tf_static', self._on_tf_static,
                                           TF_STATIC_QOS)]

    def stop(self) -> None:
        """Stop listening to TF (deactivate) and forget what it said."""
        if self._tf2 is not None:
            self._tf2[1].unregister()
        for subscription in self._subscriptions:
            self._node.destroy_subscription(subscription)
        with self._lock:
            self._subscriptions, self._buffer, self._tf2 = [], None, None

    def lookup(self, fixed_frame: str, header: Header) -> np.ndarray:
        """
        (4, 4) ``fixed_frame``_from_camera at the image's stamp, as TF holds it now.

        Raises:
            TransformUnavailable: TF cannot give it (yet: ``still_to_come``).
            InputError: the image has no frame_id.

        """
        if not header.frame_id:
            raise InputError('the image has no frame_id')
        tf2 = self._tf2
        if tf2 is not None:
            try:
                stamped = tf2[0].lookup_transform(fixed_frame, header.frame_id, header.stamp)
            except tf2_ros.TransformException as err:
                raise TransformUnavailable(str(err)) from err
            return transform_matrix(stamped.transform)
        with self._lock:
            if self._buffer is None:
                raise TransformUnavailable('not listening to TF (inactive)')
            return self._buffer.lookup(fixed_frame, header.frame_id, stamp_to_ns(header.stamp))

    def _on_tf(self, message: TFMessage, static: bool = False) -> None:
        topic = '/tf_static' if static else '/tf'
        for transform in message.transforms:
            t, q = transform.transform.translation, transform.transform.rotation
            try:
                with self._lock:
                    if self._buffer is None:
                        return
                    went_back = self._buffer.set_transform(
                        transform.header.frame_id, transform.child_frame_id,
                        stamp_to_ns(transform.header.stamp), [t.x, t.y, t.z],
                        [q.x, q.y, q.z, q.w], static)
            except InputError as err:
                self._problems.warn('map_bad_transform', transform.child_frame_id,
                                    f'{topic}: {err}; ignored')
                continue
            if went_back:
                self._node.get_logger().info(f'{topic}: the clock went back (a bag '
                                             'restarted?): the TF buffer was cleared')

    def _on_tf_static(self, message: TFMessage) -> None:
        self._on_tf(message, static=True)


def still_to_come(err: Exception) -> bool:
    """
    Tell whether a failed lookup may succeed later: TF lacks data still to come.

    A frame TF has not seen yet, or a stamp past its newest transform (the wording of
    ``TransformBuffer`` and of tf2); not two trees, a stamp in the past or a bad frame id.
    """
    text = str(err)
    return any(words in text for words in ('future', 'not in the TF tree', 'does not exist'))
