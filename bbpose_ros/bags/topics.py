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

"""Topic names, frame ids and message helpers shared by the bag writer and reader."""

from typing import Any

import numpy as np
import numpy.typing as npt

from bbpose_ros.bags.typestore import TYPESTORE
from bbpose_ros.core.geometry.rotations import (matrix_to_quat_wxyz, quat_wxyz_to_matrix,
                                                wxyz_to_xyzw)
from bbpose_ros.core.geometry.rotations import xyzw_to_wxyz

IMAGE_TOPIC = '/camera/image_raw'
CAMERA_INFO_TOPIC = '/camera/camera_info'
DEFAULT_FRAME_ID = 'camera_color_optical_frame'
GROUND_TRUTH_PREFIX = '/ground_truth/'

IMAGE_TYPE = 'sensor_msgs/msg/Image'
COMPRESSED_IMAGE_TYPE = 'sensor_msgs/msg/CompressedImage'
# image_transport's compressed transport: its topic is the image topic + this suffix.
COMPRESSED_SUFFIX = '/compressed'
CAMERA_INFO_TYPE = 'sensor_msgs/msg/CameraInfo'
POSE_TYPE = 'geometry_msgs/msg/PoseStamped'
# The camera's pose in a fixed frame, where the frames have one (BOP's cam_R_w2c, cam_t_w2c),
# as a robot's TF gives it; and where each static scene begins (its id in the frame_id).
TF_TOPIC = '/tf'
TF_TYPE = 'tf2_msgs/msg/TFMessage'
FIXED_FRAME = 'world'
SCENE_TOPIC = '/ground_truth/scene'
SCENE_TYPE = 'std_msgs/msg/Header'


def compressed_topic(image_topic: str) -> str:
    """Topic of image_transport's compressed images of ``image_topic``, e.g. .../compressed."""
    return image_topic + COMPRESSED_SUFFIX


def ground_truth_topic(object_name: str) -> str:
    """Topic of an object's ground-truth poses, e.g. /ground_truth/ape/pose."""
    return f'{GROUND_TRUTH_PREFIX}{object_name}/pose'


def object_of_ground_truth_topic(topic: str) -> str | None:
    """Object name of a ground-truth topic, or None for other topics."""
    if topic.startswith(GROUND_TRUTH_PREFIX) and topic.endswith('/pose'):
        return topic[len(GROUND_TRUTH_PREFIX):-len('/pose')]
    return None


def header(stamp_ns: int, frame_id: str) -> Any:
    """Build a std_msgs/Header for a stamp in nanoseconds."""
    types = TYPESTORE.types
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    stamp = types['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec)
    return types['std_msgs/msg/Header'](stamp=stamp, frame_id=frame_id)


def pose_message(stamp_ns: int, frame_id: str, rotation: npt.ArrayLike,
                 translation_m: npt.ArrayLike) -> Any:
    """geometry_msgs/PoseStamped for x_cam = R x_model + t (metres, ROS (x, y, z, w))."""
    types = TYPESTORE.types
    x, y, z, w = wxyz_to_xyzw(matrix_to_quat_wxyz(rotation))
    pose = types['geometry_msgs/msg/Pose'](
        position=types['geometry_msgs/msg/Point'](*(float(v) for v in translation_m)),
        orientation=types['geometry_msgs/msg/Quaternion'](x=x, y=y, z=z, w=w))
    return types[POSE_TYPE](header=header(stamp_ns, frame_id), pose=pose)


def transform_message(stamp_ns: int, parent: str, child: str,
                      parent_from_child: npt.ArrayLike) -> Any:
    """tf2_msgs/TFMessage of one transform: the child frame's (4, 4) pose in the parent."""
    types = TYPESTORE.types
    matrix = np.asarray(parent_from_child, dtype=float)
    x, y, z, w = wxyz_to_xyzw(matrix_to_quat_wxyz(matrix[:3, :3]))
    transform = types['geometry_msgs/msg/Transform'](
        translation=types['geometry_msgs/msg/Vector3'](*(float(v) for v in matrix[:3, 3])),
        rotation=types['geometry_msgs/msg/Quaternion'](x=x, y=y, z=z, w=w))
    stamped = types['geometry_msgs/msg/TransformStamped'](
        header=header(stamp_ns, parent), child_frame_id=child, transform=transform)
    return types[TF_TYPE](transforms=[stamped])


def pose_from_message(message: Any) -> tuple[np.ndarray, np.ndarray]:
    """(rotation (3, 3), translation (3,) metres) of a PoseStamped."""
    q = message.pose.orientation
    p = message.pose.position
    return (quat_wxyz_to_matrix(xyzw_to_wxyz([q.x, q.y, q.z, q.w])),
            np.array([p.x, p.y, p.z], dtype=float))
