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
The outputs robot stacks consume: vision_msgs/Detection3DArray and tf2_msgs/TFMessage.

Both are made from a frame's PoseEstimates and the geometry_msgs/Pose of each (metres, ROS
quaternion order x, y, z, w; x_cam = R x_model + t, in the image's optical frame), which
``conversions.poses_to_messages`` makes once per frame for every output.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from geometry_msgs.msg import Point, Pose, PoseWithCovariance, Transform, TransformStamped
from geometry_msgs.msg import Vector3
import numpy as np
from rclpy.qos import QoSProfile
from std_msgs.msg import Header
from tf2_msgs.msg import TFMessage
from vision_msgs.msg import BoundingBox3D, Detection3D, Detection3DArray, ObjectHypothesis
from vision_msgs.msg import ObjectHypothesisWithPose

from bbpose_ros.core.data.models import ObjectModel
from bbpose_ros.core.pipeline.poses import PoseEstimate

DETECTIONS_TOPIC = '~/detections'
TF_TOPIC = '/tf'
# tf2_ros's TransformBroadcaster QoS (reliable, volatile, keep last 100): what tf2 listeners
# of a full ROS install expect on /tf.
TF_QOS = QoSProfile(depth=100)


def instance_names(poses: Sequence[PoseEstimate]) -> list[str]:
    """
    Name each pose of a frame: its object's name, then ``<name>_<k>`` for the k-th repeat.

    The first pose of an object in the frame (the detector lists its instances best-scored
    first) keeps the plain name, so with one instance per object (``max_instances: 1``)
    the names never change; ``ape``, ``ape_1``, ``ape_2`` when three apes are found.
    """
    seen = {}
    names = []
    for pose in poses:
        k = seen[pose.object_name] = seen.get(pose.object_name, -1) + 1
        names.append(pose.object_name if k == 0 else f'{pose.object_name}_{k}')
    return names


class DetectionsBuilder:
    """
    Makes a frame's Detection3DArray and TFMessage from its PoseEstimates.

    Each Detection3D has one result: class_id the object's name, score the pose's
    confidence, the pose (of the model origin; covariance all zero: not estimated); its
    bbox is the axis-aligned box of the mesh in the model frame, posed with the object
    (centre R c + t, size the box's edge lengths in metres), and its id is empty. The
    boxes of each object are measured once, here.

    Args:
        models: {object name: ObjectModel}.

    """

    def __init__(self, models: Mapping[str, ObjectModel]) -> None:
        self._boxes = {name: box_of(model) for name, model in models.items()}

    def __call__(self, header: Header, poses: Sequence[PoseEstimate],
                 pose_msgs: Sequence[Pose]) -> Detection3DArray:
        """Return the Detection3DArray of a frame (one Detection3D per pose, ``header``)."""
        detections = []
        for pose, pose_msg in zip(poses, pose_msgs):
            centre_model, size = self._boxes[pose.object_name]
            centre = pose.rotation @ centre_model + pose.translation
            result = ObjectHypothesisWithPose(
                hypothesis=ObjectHypothesis(class_id=pose.object_name,
                                            score=float(pose.confidence)),
                pose=PoseWithCovariance(pose=pose_msg))
            box = BoundingBox3D(
                center=Pose(position=Point(x=float(centre[0]), y=float(centre[1]),
                                           z=float(centre[2])),
                            orientation=pose_msg.orientation),
                size=Vector3(x=float(size[0]), y=float(size[1]), z=float(size[2])))
            detections.append(Detection3D(header=header, results=[result], bbox=box))
        return Detection3DArray(header=header, detections=detections)


def transforms(header: Header, poses: Sequence[PoseEstimate], pose_msgs: Sequence[Pose],
               prefix: str = '') -> TFMessage:
    """
    Return the TFMessage of a frame: one transform per pose, image frame -> object.

    Parent: ``header.frame_id``; child: ``prefix`` + the pose's ``instance_names`` name;
    stamp: the image's. The transform maps model coordinates into the image frame.
    """
    return TFMessage(transforms=[
        TransformStamped(header=header, child_frame_id=prefix + name, transform=Transform(
            translation=Vector3(x=pose_msg.position.x, y=pose_msg.position.y,
                                z=pose_msg.position.z),
            rotation=pose_msg.orientation))
        for name, pose_msg in zip(instance_names(poses), pose_msgs)])


def box_of(model: ObjectModel) -> tuple[np.ndarray, np.ndarray]:
    """(centre (3,), size (3,)) of a model's axis-aligned box, metres, model frame."""
    corners = model.box_corners
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    return (lo + hi) / 2, hi - lo
