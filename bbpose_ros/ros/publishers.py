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
The node's lifecycle publishers, and what they publish for each answered frame.

Made by the configure transition, enabled by activate (rclpy's LifecycleNode enables every
lifecycle publisher), destroyed by cleanup. Per frame, all stamped with the image's header:
one PoseStamped per pose on ``~/<object>/pose``; the Detection3DArray and the /tf
transforms, each made only while it has subscribers; the MarkerArray, which marks the frame
answered; the debug image, only while it has subscribers.
"""

from collections.abc import Sequence

from geometry_msgs.msg import PoseStamped
import numpy as np
from rclpy.lifecycle import LifecycleNode, LifecyclePublisher
from sensor_msgs.msg import Image
from std_msgs.msg import Header
from tf2_msgs.msg import TFMessage
from vision_msgs.msg import Detection3DArray
from visualization_msgs.msg import MarkerArray

from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.pipeline.overlays import draw_estimates
from bbpose_ros.core.pipeline.poses import PoseEstimate
from bbpose_ros.ros import conversions, detections
from bbpose_ros.ros.node_pipeline import NodePipeline


class FramePublishers:
    """
    The publishers of the node's outputs; the worker thread publishes through them.

    Args:
        node: the node they belong to; its ``publish_tf``, ``publish_debug_image`` and
            ``tf_prefix`` parameters are read for every frame.

    """

    def __init__(self, node: LifecycleNode) -> None:
        self._node = node
        self._poses: dict[str, LifecyclePublisher] = {}    # by object name
        self._markers: LifecyclePublisher | None = None
        self._detections: LifecyclePublisher | None = None
        self._tf: LifecyclePublisher | None = None
        self._debug_image: LifecyclePublisher | None = None
        self._frame_id = ''                                # of the last frame published

    def create(self, objects: Sequence[str]) -> None:
        """Create every publisher (configure): a pose topic per object, then the others."""
        node = self._node
        self._poses = {}
        self.add_objects(objects, enabled=False)
        self._markers = node.create_lifecycle_publisher(MarkerArray, '~/markers', 10)
        self._detections = node.create_lifecycle_publisher(
            Detection3DArray, detections.DETECTIONS_TOPIC, 10)
        self._tf = node.create_lifecycle_publisher(TFMessage, detections.TF_TOPIC,
                                                   detections.TF_QOS)
        self._debug_image = node.create_lifecycle_publisher(Image, '~/debug_image', 1)

    def add_objects(self, names: Sequence[str], enabled: bool) -> None:
        """Create the pose publishers of new object ``names``; ``enabled``: the node serves."""
        added = {name: self._node.create_lifecycle_publisher(PoseStamped, f'~/{name}/pose', 10)
                 for name in names if name not in self._poses}
        if enabled:
            for publisher in added.values():
                publisher.on_activate(None)     # rclpy's managed entities ignore the state
        self._poses = {**self._poses, **added}    # swapped whole: the worker reads it

    def destroy(self) -> None:
        """Destroy every publisher (cleanup, shutdown); ``create`` makes them again."""
        publishers = [*self._poses.values(), self._markers, self._detections, self._tf,
                      self._debug_image]
        for publisher in publishers:
            if publisher is not None:
                self._node.destroy_lifecycle_publisher(publisher)
        self._poses = {}
        self._markers = self._detections = self._tf = self._debug_image = None

    def publish(self, header: Header, image_rgb: np.ndarray, intrinsics: CameraIntrinsics,
                poses: Sequence[PoseEstimate], pipeline: NodePipeline) -> None:
        """
        Publish a frame's outputs: poses, detections, TF, markers, then the debug image.

        ``image_rgb`` is the (H, W, 3) uint8 image the poses were estimated on (rectified),
        ``intrinsics`` its camera; the poses are in metres in the frame ``header`` names.
        """
        node = self._node
        stamped, markers = conversions.frame_messages(header, poses, pipeline.markers)
        prefix = detections.resolve_prefix(node.get_parameter('tf_prefix').value,
                                           node.get_fully_qualified_name())
        for name, message in stamped:
            self._poses[name].publish(message)
        # Made only for subscribers, as the debug image: rclpy messages are slow to build
        # (docs/experiments.md).
        pose_msgs = [message.pose for _, message in stamped]
        if self._detections.get_subscription_count() > 0:
            self._detections.publish(pipeline.detections(header, poses, pose_msgs, prefix))
        if poses and header.frame_id and node.get_parameter('publish_tf').value and \
                self._tf.get_subscription_count() > 0:
            self._tf.publish(detections.transforms(header, poses, pose_msgs, prefix))
        self._markers.publish(markers)
        self._frame_id = header.frame_id
        if node.get_parameter('publish_debug_image').value and \
                self._debug_image.get_subscription_count() > 0:
            self._debug_image.publish(conversions.rgb_to_image(
                header, draw_estimates(image_rgb, intrinsics, pipeline.pipeline.models, poses)))

    def clear_markers(self) -> None:
        """Publish one DELETEALL, stamped now in the last frame's frame_id: boxes leave RViz."""
        header = Header(stamp=self._node.get_clock().now().to_msg(), frame_id=self._frame_id)
        self._markers.publish(conversions.delete_all_markers(header))
