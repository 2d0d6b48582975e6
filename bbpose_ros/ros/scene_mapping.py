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
The node's map of the scene: TF in, each answered frame's poses fused in ``fixed_frame``.

With ``fixed_frame`` set (e.g. ``world``, ``base_link``), the node keeps the camera's pose
from ``/tf`` and ``/tf_static``: tf2_ros's buffer and listener where tf2_ros is installed,
else ``core.scene.transform_buffer.TransformBuffer`` fed by its own subscriptions (the
wheel venv has no tf2_ros). After a frame's own outputs are published, the camera's pose in
``fixed_frame`` at the image's stamp joins the frame's poses to the map
(``core.scene.object_map.ObjectMap``), and the map is published, stamped with the image's
stamp in ``fixed_frame``:

* ``~/map/<object>/pose`` (geometry_msgs/PoseStamped);
* ``~/map/detections`` (vision_msgs/Detection3DArray), while subscribed: one Detection3D
  per object, id its TF child frame, score the map's confidence, the position covariance
  the map's;
* ``/tf``, with ``publish_tf`` and while subscribed: ``fixed_frame`` ->
  ``<tf_prefix>map/<object>``;
* ``~/map/markers`` (visualization_msgs/MarkerArray), while subscribed: box and "name
  confidence age" label.

The service ``~/clear_map`` (std_srvs/Trigger) forgets every object (a new scene). A frame
whose camera pose TF cannot give is answered per frame only, counted
(``warnings_map_no_transform``) and logged; a transform TF messages carry that the buffer
refuses (NaN, not a rotation, a second parent) is counted (``warnings_map_bad_transform``)
and logged, and changes nothing. Map settings changed at run time (``map_*``) start a new
map.
"""

from __future__ import annotations

from collections.abc import Sequence
import threading
import time

from geometry_msgs.msg import PoseStamped
import numpy as np
from rclpy.duration import Duration
from rclpy.lifecycle import LifecycleNode, LifecyclePublisher
from rclpy.qos import DurabilityPolicy, QoSProfile
from std_msgs.msg import Header
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage
from vision_msgs.msg import Detection3DArray
from visualization_msgs.msg import MarkerArray

from bbpose_ros.core.data.stamps import stamp_to_ns
from bbpose_ros.core.geometry.rigid import transform_matrix
from bbpose_ros.core.pipeline.poses import Detection, PoseEstimate
from bbpose_ros.core.scene.object_map import MapObject, ObjectMap
from bbpose_ros.core.scene.transform_buffer import TransformBuffer, TransformUnavailable
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.ros import conversions, detections
from bbpose_ros.ros.node_pipeline import NodePipeline
from bbpose_ros.ros.throttle import ProblemLog

try:
    import tf2_ros
except ImportError:         # the wheel venv: TransformBuffer stands in
    tf2_ros = None

# tf2_ros's listener QoS: /tf reliable, keep last 100; /tf_static transient local too, so
# the static transforms sent before the node started arrive.
TF_LISTENER_QOS = QoSProfile(depth=100)
TF_STATIC_QOS = QoSProfile(depth=100, durability=DurabilityPolicy.TRANSIENT_LOCAL)
MAP_FRAME_PREFIX = 'map/'
# TF may arrive a little after the image it places (another topic, another sender): a
# lookup waits this long for it, as tf2_ros's lookup_transform with a timeout does.
TF_WAIT_S = 0.1
TF_POLL_S = 0.005


class SceneMapping:
    """
    The map of the scene in ``fixed_frame`` and its outputs (module docstring).

    Args:
        node: the node; its ``fixed_frame``, ``publish_tf`` and ``tf_prefix`` parameters
            are read (``fixed_frame`` at ``create``).
        problems: counts and logs what TF cannot give or the buffer refuses.

    """

    def __init__(self, node: LifecycleNode, problems: ProblemLog) -> None:
        self._node = node
        self._problems = problems
        self._lock = threading.Lock()   # the map and the buffer: worker vs executor
        self._map: ObjectMap | None = None
        self._buffer: TransformBuffer | None = None
        self._tf2 = None                # (tf2_ros.Buffer, its TransformListener)
        self._subscriptions = []
        self._publishers: dict[str, LifecyclePublisher] = {}
        self._poses: dict[str, LifecyclePublisher] = {}
        self.fixed_frame = ''
        node.create_service(Trigger, '~/clear_map', self._on_clear)

    def create(self, objects: Sequence[str]) -> None:
        """Read ``fixed_frame``; with one, create the map's publishers (configure)."""
        node = self._node
        self.fixed_frame = node.get_parameter('fixed_frame').value
        if not self.fixed_frame:
            return
        self._publishers = {
            'detections': node.create_lifecycle_publisher(Detection3DArray,
                                                          '~/map/detections', 10),
            'markers': node.create_lifecycle_publisher(MarkerArray, '~/map/markers', 10),
            'tf': node.create_lifecycle_publisher(TFMessage, detections.TF_TOPIC,
                                                  detections.TF_QOS)}
        self.add_objects(objects, enabled=False)

    def add_objects(self, names: Sequence[str], enabled: bool) -> None:
        """Create the map pose publishers of new object ``names``; ``enabled``: serving."""
        if not self.fixed_frame:
            return
        added = {name: self._node.create_lifecycle_publisher(PoseStamped,
                                                             f'~/map/{name}/pose', 10)
                 for name in names if name not in self._poses}
        if enabled:
            for publisher in added.values():
                publisher.on_activate(None)
        self._poses = {**self._poses, **added}

    def subscribe(self) -> None:
        """Start listening to TF (activate), with tf2_ros where installed."""
        if not self.fixed_frame:
            return
        if tf2_ros is not None:
            buffer = tf2_ros.Buffer()
            self._tf2 = (buffer, tf2_ros.TransformListener(buffer, self._node))
            return
        self._buffer = TransformBuffer()
        self._subscriptions = [
            self._node.create_subscription(TFMessage, '/tf', self._on_tf, TF_LISTENER_QOS),
            self._node.create_subscription(TFMessage, '/tf_static', self._on_tf_static,
                                           TF_STATIC_QOS)]

    def unsubscribe(self) -> None:
        """Stop listening to TF (deactivate); the map is kept."""
        if self._tf2 is not None:
            self._tf2[1].unregister()
        for subscription in self._subscriptions:
            self._node.destroy_subscription(subscription)
        self._subscriptions, self._buffer, self._tf2 = [], None, None

    def destroy(self) -> None:
        """Destroy the publishers and forget the map (cleanup)."""
        self.unsubscribe()
        for publisher in [*self._publishers.values(), *self._poses.values()]:
            self._node.destroy_lifecycle_publisher(publisher)
        self._publishers, self._poses, self._map = {}, {}, None

    def observe(self, header: Header, camera, poses: Sequence[PoseEstimate],
                pipeline: NodePipeline) -> bool:
        """
        Add an answered frame's poses to the map and publish it; tell whether it was added.

        ``camera``: the image's CameraIntrinsics; ``poses`` in the frame ``header`` names.
        """
        if not self.fixed_frame or not self._publishers:
            return False
        stamp_ns = stamp_to_ns(header.stamp)
        try:
            world_from_camera = self._camera_pose(header.frame_id, header)
        except (TransformUnavailable, InputError) as err:
            self._problems.warn('map_no_transform', header.frame_id,
                                f'no camera pose for the map: {self.fixed_frame} <- '
                                f'{header.frame_id or "(empty frame_id)"}: {err}; the frame '
                                'is answered without it')
            return False
        options, models = pipeline.pipeline.options, pipeline.pipeline.models
        try:
            with self._lock:
                if self._map is None or self._map.options != options or \
                        self._map.models is not models:     # a rebuild: new settings, objects
                    self._map = ObjectMap(models, options)
                self._map.add_view(stamp_ns, world_from_camera, camera, poses)
                objects = self._map.objects()
        except Exception as err:  # noqa: B902 - the frame is answered; the map goes on
            self._problems.warn('map_failed', type(err).__name__,
                                f'the map could not take the frame: {type(err).__name__}: {err}')
            return False
        self._publish(Header(stamp=header.stamp, frame_id=self.fixed_frame), objects,
                      stamp_ns, pipeline)
        return True

    def _camera_pose(self, frame_id, header):
        """(4, 4) fixed_frame_from_camera at the image's stamp."""
        if not frame_id:
            raise InputError('the image has no frame_id')
        if self._tf2 is not None:
            try:
                stamped = self._tf2[0].lookup_transform(self.fixed_frame, frame_id,
                                                        header.stamp, Duration(seconds=TF_WAIT_S))
            except tf2_ros.TransformException as err:
                raise TransformUnavailable(str(err)) from err
            return transform_matrix(stamped.transform)
        deadline = time.monotonic() + TF_WAIT_S
        while True:
            if self._buffer is None:
                raise TransformUnavailable('not listening to TF (inactive)')
            try:
                with self._lock:
                    return self._buffer.lookup(self.fixed_frame, frame_id,
                                               stamp_to_ns(header.stamp))
            except TransformUnavailable as err:
                # Only data still to come is waited for: a frame TF has not seen yet, or a
                # stamp past its newest transform; not two trees or a stamp in the past.
                late = 'future' in str(err) or 'not in the TF tree' in str(err)
                if not late or time.monotonic() > deadline:
                    raise
            time.sleep(TF_POLL_S)

    def _publish(self, header, objects, now_ns, pipeline):
        """Publish the map: poses always, detections, TF and markers while subscribed."""
        node, publishers = self._node, self._publishers
        poses = [PoseEstimate(Detection(o.object_name, o.confidence, np.zeros(4)), o.rotation,
                              o.translation, o.confidence, 'map') for o in objects]
        pose_msgs = conversions.poses_to_messages(poses)
        for pose, pose_msg in zip(poses, pose_msgs):
            self._poses[pose.object_name].publish(PoseStamped(header=header, pose=pose_msg))
        prefix = detections.resolve_prefix(node.get_parameter('tf_prefix').value,
                                           node.get_fully_qualified_name()) + MAP_FRAME_PREFIX
        if publishers['detections'].get_subscription_count() > 0:
            array = pipeline.detections(header, poses, pose_msgs, prefix)
            for detection, item in zip(array.detections, objects):
                _set_position_covariance(detection.results[0].pose.covariance, item)
            publishers['detections'].publish(array)
        if poses and node.get_parameter('publish_tf').value and \
                publishers['tf'].get_subscription_count() > 0:
            publishers['tf'].publish(detections.transforms(header, poses, pose_msgs, prefix))
        if publishers['markers'].get_subscription_count() > 0:
            labels = [f'{o.object_name} {o.confidence:.2f} {o.age_s(now_ns):.0f}s'
                      for o in objects]
            publishers['markers'].publish(pipeline.markers(header, poses, pose_msgs, labels))

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

    def _on_clear(self, request: Trigger.Request, response: Trigger.Response
                  ) -> Trigger.Response:
        with self._lock:
            count = 0 if self._map is None else len(self._map.objects())
            if self._map is not None:
                self._map.clear()
        response.success = bool(self.fixed_frame)
        response.message = (f'map cleared ({count} objects forgotten)' if self.fixed_frame
                            else 'no map: the parameter fixed_frame is empty')
        self._node.get_logger().info(response.message)
        return response


def _set_position_covariance(covariance, item: MapObject) -> None:
    """Put the map's (3, 3) translation covariance into a 6 x 6 pose covariance (in place)."""
    for i in range(3):
        for j in range(3):
            covariance[6 * i + j] = float(item.covariance[i, j])
