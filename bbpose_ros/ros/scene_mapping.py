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
from ``/tf`` and ``/tf_static`` (``camera_poses.CameraPoses``). After a frame's own outputs
are published, the camera's pose in ``fixed_frame`` at the image's stamp joins the frame's
poses to the map (``core.scene.object_map.ObjectMap``), and the map is published, stamped
with the image's stamp in ``fixed_frame``:

* ``~/map/<object>/pose`` (geometry_msgs/PoseStamped);
* ``~/map/detections`` (vision_msgs/Detection3DArray), while subscribed: one Detection3D
  per object, id its TF child frame, score the map's confidence, the position covariance
  the map's;
* ``/tf``, with ``publish_tf`` and while subscribed: ``fixed_frame`` ->
  ``<tf_prefix>map/<object>``;
* ``~/map/markers`` (visualization_msgs/MarkerArray), while subscribed: box and "name
  confidence age" label.

The service ``~/clear_map`` (std_srvs/Trigger) forgets every object (a new scene).

TF may come after the image it places (another topic, another sender, a transform
published a little behind the camera): as tf2_ros's MessageFilter queues a message, an
answered frame whose camera pose TF does not hold yet waits, in order, until TF places it
(the map then takes it and is published with its stamp) or ``TF_TIMEOUT_S`` has passed;
the worker never blocks on TF. A frame whose camera pose TF cannot give is answered per
frame only, counted (``warnings_map_no_transform``) and logged. Map settings changed at run
time (``map_*``) start a new map.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
import threading
import time

from geometry_msgs.msg import PoseStamped
import numpy as np
from rclpy.lifecycle import LifecycleNode, LifecyclePublisher
from std_msgs.msg import Header
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage
from vision_msgs.msg import Detection3DArray
from visualization_msgs.msg import MarkerArray

from bbpose_ros.core.data.stamps import stamp_to_ns
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.pipeline.poses import Detection, PoseEstimate
from bbpose_ros.core.scene.kernels import compile_kernels
from bbpose_ros.core.scene.object_map import MapObject, ObjectMap
from bbpose_ros.core.scene.transform_buffer import TransformUnavailable
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.ros import conversions, detections
from bbpose_ros.ros.camera_poses import CameraPoses, still_to_come
from bbpose_ros.ros.node_pipeline import NodePipeline
from bbpose_ros.ros.throttle import ProblemLog

MAP_FRAME_PREFIX = 'map/'
# An answered frame waits this long for the TF that places it (module docstring), at most
# MAX_WAITING frames at a time (the oldest gives way); waiting frames are retried whenever
# another frame comes and, while any waits, every RETRY_S seconds (a timer, else cancelled).
TF_TIMEOUT_S = 1.0
MAX_WAITING = 64
RETRY_S = 0.02


@dataclass
class _Waiting:
    """An answered frame waiting for its camera pose: what the map needs of it."""

    header: Header
    camera: CameraIntrinsics
    poses: Sequence[PoseEstimate]
    pipeline: NodePipeline
    deadline_s: float                   # time.monotonic() after which it is given up
    mapped: bool = False


class SceneMapping:
    """
    The map of the scene in ``fixed_frame`` and its outputs (module docstring).

    Args:
        node: the node; its ``fixed_frame``, ``publish_tf`` and ``tf_prefix`` parameters
            are read (``fixed_frame`` at ``create``).
        problems: counts and logs what TF cannot give or the buffer refuses.
        count: counts a frame the map took (``count('mapped')``).

    """

    def __init__(self, node: LifecycleNode, problems: ProblemLog,
                 count: Callable[[str], None]) -> None:
        self._node = node
        self._problems = problems
        self._count = count
        # The waiting frames and the map: the worker, the retry timer and clear_map.
        self._lock = threading.Lock()
        self._waiting: deque[_Waiting] = deque()
        self._retry = None              # the timer retrying waiting frames (active)
        self._map: ObjectMap | None = None
        self._tf = CameraPoses(node, problems)
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
        compile_kernels()       # loaded from numba's cache: not in the first frame's worker
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
        """Start listening to TF and retrying waiting frames (activate)."""
        if not self.fixed_frame:
            return
        self._tf.listen()
        self._retry = self._node.create_timer(RETRY_S, self._take_waiting)
        self._retry.cancel()            # runs only while frames wait

    def unsubscribe(self) -> None:
        """Stop listening to TF (deactivate); the map is kept, waiting frames are not."""
        with self._lock:
            self._waiting.clear()
            if self._retry is not None:
                self._node.destroy_timer(self._retry)
                self._retry = None
        self._tf.stop()

    def destroy(self) -> None:
        """Destroy the publishers and forget the map (cleanup)."""
        self.unsubscribe()
        for publisher in [*self._publishers.values(), *self._poses.values()]:
            self._node.destroy_lifecycle_publisher(publisher)
        self._publishers, self._poses, self._map = {}, {}, None

    def observe(self, header: Header, camera: CameraIntrinsics,
                poses: Sequence[PoseEstimate], pipeline: NodePipeline) -> bool:
        """
        Offer an answered frame's poses to the map; tell whether the map took it now.

        ``poses`` are in the frame ``header`` names. A frame TF cannot place yet waits
        (module docstring); frames waiting before it are taken first.
        """
        if not self.fixed_frame or not self._publishers:
            return False
        waiting = _Waiting(header, camera, poses, pipeline, time.monotonic() + TF_TIMEOUT_S)
        with self._lock:
            if len(self._waiting) >= MAX_WAITING:
                self._give_up(self._waiting.popleft(), 'too many frames wait for TF')
            self._waiting.append(waiting)
        self._take_waiting()
        return waiting.mapped

    def _take_waiting(self) -> None:
        """Map the waiting frames in order while TF places them; give up the expired."""
        with self._lock:
            while self._waiting:
                waiting = self._waiting[0]
                try:
                    world_from_camera = self._tf.lookup(self.fixed_frame, waiting.header)
                except (TransformUnavailable, InputError) as err:
                    if still_to_come(err) and time.monotonic() < waiting.deadline_s:
                        if self._retry is not None and self._retry.is_canceled():
                            self._retry.reset()
                        return
                    self._give_up(self._waiting.popleft(), str(err))
                    continue
                self._waiting.popleft()
                waiting.mapped = self._add(waiting, world_from_camera)
            if self._retry is not None:
                self._retry.cancel()

    def _give_up(self, waiting: _Waiting, reason: str) -> None:
        """Count and log a frame the map cannot take for want of its camera pose."""
        frame_id = waiting.header.frame_id
        self._problems.warn('map_no_transform', frame_id,
                            f'no camera pose for the map: {self.fixed_frame} <- '
                            f'{frame_id or "(empty frame_id)"}: {reason}; the frame is '
                            'answered without it')

    def _add(self, waiting: _Waiting, world_from_camera: np.ndarray) -> bool:
        """
        Add one frame's poses to the map and publish the map; tell whether it took them.

        Called with ``_lock`` held (``_take_waiting``).
        """
        header, pipeline = waiting.header, waiting.pipeline
        stamp_ns = stamp_to_ns(header.stamp)
        options, models = pipeline.pipeline.options, pipeline.pipeline.models
        try:
            if self._map is None or self._map.options != options or \
                    self._map.models is not models:     # a rebuild: new settings, objects
                self._map = ObjectMap(models, options)
            self._map.add_view(stamp_ns, world_from_camera, waiting.camera, waiting.poses)
            objects = self._map.objects()
        except Exception as err:  # noqa: B902 - the frame is answered; the map goes on
            self._problems.warn('map_failed', type(err).__name__,
                                f'the map could not take the frame: {type(err).__name__}: {err}')
            return False
        self._count('mapped')
        self._publish(Header(stamp=header.stamp, frame_id=self.fixed_frame), objects,
                      stamp_ns, pipeline)
        return True

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
