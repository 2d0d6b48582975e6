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

Each pose is named once per frame (``frame_names``): the TF child frame and the Detection3D
``id`` are the same string, ``<prefix><object>`` (``<object>_<k>`` for the k-th further
instance of an object in the frame). The default prefix ``~/`` stands for the node's
fully qualified name (``bbpose_node/ape``), so two nodes never publish the same frame.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
import json
from pathlib import Path

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
# The per-object pose spread measured on the development frames (``cli/pose_spread.py``).
POSE_SPREAD_FILE = Path(__file__).resolve().parents[1] / 'weights' / 'pose_spread.json'
# The prefix that stands for the node's fully qualified name (tf_prefix).
NODE_PREFIX = '~/'
# A confidence below this is taken as this when scaling the spread: a pose of almost no
# confidence gets a large, finite covariance.
MIN_CONFIDENCE = 0.05
TF_TOPIC = '/tf'
# tf2_ros's TransformBroadcaster QoS (reliable, volatile, keep last 100): what tf2 listeners
# of a full ROS install expect on /tf.
TF_QOS = QoSProfile(depth=100)


def resolve_prefix(prefix: str, node_name: str) -> str:
    """
    Return the TF frame prefix of parameter ``tf_prefix``.

    ``~/`` at its start stands for ``node_name`` (the fully qualified name, its leading
    slash dropped) and a slash: ``~/`` on /cam1/bbpose_node is ``cam1/bbpose_node/``.
    """
    if prefix.startswith(NODE_PREFIX):
        return f'{node_name.lstrip("/")}/{prefix[len(NODE_PREFIX):]}'
    return prefix


def frame_names(poses: Sequence[PoseEstimate], prefix: str) -> list[str]:
    """Return each pose's TF child frame and Detection3D id: ``prefix`` + its instance name."""
    return [prefix + name for name in instance_names(poses)]


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


@dataclass(frozen=True)
class ObjectSpread:
    """
    How far an object's poses typically are from the truth, at a typical confidence.

    Attributes:
        sigma_m: (3,) translation error spread along the camera's x, y, z, metres.
        sigma_rad: (3,) rotation error spread about the camera's x, y, z, radians.
        confidence_median: the median confidence of the poses it was measured on.

    """

    sigma_m: tuple[float, float, float]
    sigma_rad: tuple[float, float, float]
    confidence_median: float

    def covariance(self, confidence: float) -> list[float]:
        """
        Return a pose's row-major 6x6 covariance: x, y, z, rotation about x, y, z.

        Diagonal: the spread scaled by ``confidence_median / confidence``, squared; a pose
        as confident as the typical measured one gets the measured spread.
        """
        scale = self.confidence_median / max(float(confidence), MIN_CONFIDENCE)
        variances = (np.concatenate([self.sigma_m, self.sigma_rad]) * scale) ** 2
        return np.diag(variances).reshape(-1).tolist()


def load_pose_spread(path: Path = POSE_SPREAD_FILE) -> dict[str, ObjectSpread]:
    """Return {object name: ObjectSpread} of a pose_spread.json ({} when it is missing)."""
    if not Path(path).is_file():
        return {}
    objects = json.loads(Path(path).read_text())['objects']
    return {name: ObjectSpread(tuple(entry['sigma_m']), tuple(entry['sigma_rad']),
                               entry['confidence_median'])
            for name, entry in objects.items()}


class DetectionsBuilder:
    """
    Makes a frame's Detection3DArray and TFMessage from its PoseEstimates.

    Each Detection3D has one result: class_id the object's name, score the pose's
    confidence, the pose (of the model origin) with the covariance of its object's
    ObjectSpread (all zero, i.e. not estimated, for an object without one); its bbox is
    the axis-aligned box of the mesh in the model frame, posed with the object (centre
    R c + t, size the box's edge lengths in metres), and its id the pose's ``frame_names``
    name (its TF child frame). The boxes of each object are measured once, here.

    Args:
        models: {object name: ObjectModel}.
        spread: {object name: ObjectSpread}; None: the shipped file's (``load_pose_spread``).

    """

    def __init__(self, models: Mapping[str, ObjectModel],
                 spread: Mapping[str, ObjectSpread] | None = None) -> None:
        self._boxes = {name: box_of(model) for name, model in models.items()}
        self._spread = dict(load_pose_spread() if spread is None else spread)

    def __call__(self, header: Header, poses: Sequence[PoseEstimate],
                 pose_msgs: Sequence[Pose], prefix: str = '') -> Detection3DArray:
        """
        Return the Detection3DArray of a frame (one Detection3D per pose, ``header``).

        ``prefix``: the TF frame prefix (``resolve_prefix``) the ids start with.
        """
        detections = []
        for pose, pose_msg, name in zip(poses, pose_msgs, frame_names(poses, prefix)):
            centre_model, size = self._boxes[pose.object_name]
            centre = pose.rotation @ centre_model + pose.translation
            spread = self._spread.get(pose.object_name)
            covariance = [0.0] * 36 if spread is None else spread.covariance(pose.confidence)
            result = ObjectHypothesisWithPose(
                hypothesis=ObjectHypothesis(class_id=pose.object_name,
                                            score=float(pose.confidence)),
                pose=PoseWithCovariance(pose=pose_msg, covariance=covariance))
            box = BoundingBox3D(
                center=Pose(position=Point(x=float(centre[0]), y=float(centre[1]),
                                           z=float(centre[2])),
                            orientation=pose_msg.orientation),
                size=Vector3(x=float(size[0]), y=float(size[1]), z=float(size[2])))
            detections.append(Detection3D(header=header, results=[result], bbox=box,
                                          id=name))
        return Detection3DArray(header=header, detections=detections)


def transforms(header: Header, poses: Sequence[PoseEstimate], pose_msgs: Sequence[Pose],
               prefix: str = '') -> TFMessage:
    """
    Return the TFMessage of a frame: one transform per pose, image frame -> object.

    Parent: ``header.frame_id``; child: the pose's ``frame_names`` name (``prefix``: a
    resolved one, ``resolve_prefix``); stamp: the image's. The transform maps model
    coordinates into the image frame.
    """
    return TFMessage(transforms=[
        TransformStamped(header=header, child_frame_id=name, transform=Transform(
            translation=Vector3(x=pose_msg.position.x, y=pose_msg.position.y,
                                z=pose_msg.position.z),
            rotation=pose_msg.orientation))
        for name, pose_msg in zip(frame_names(poses, prefix), pose_msgs)])


def box_of(model: ObjectModel) -> tuple[np.ndarray, np.ndarray]:
    """(centre (3,), size (3,)) of a model's axis-aligned box, metres, model frame."""
    corners = model.box_corners
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    return (lo + hi) / 2, hi - lo
