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
Read bags written by ``bbpose make-bag`` (or any bag with the same topics) frame by frame.

Images are raw (sensor_msgs/Image on the image topic) or image_transport's compressed
(sensor_msgs/CompressedImage, JPEG or PNG, on the image topic + /compressed):
``bag_image_source`` tells which a bag holds, ``read_bag_frames`` decodes either.
"""

from collections import defaultdict
import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Reader

from bbpose_ros.bags import topics
from bbpose_ros.bags.typestore import TYPESTORE
from bbpose_ros.core.data.compressed_image import decode_compressed
from bbpose_ros.core.data.image_encoding import decode_image
from bbpose_ros.core.data.stamps import stamp_to_ns
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.camera_info import camera_model, Rectifier
from bbpose_ros.core.geometry.rigid import transform_matrix
from bbpose_ros.core.util.errors import InputError


@dataclass
class BagFrame:
    """
    One image of a bag with what shares its stamp.

    Attributes:
        stamp_ns: header stamp of the image, nanoseconds.
        frame_id: header frame_id of the image.
        image_rgb: (H, W, 3) uint8; rectified when its CameraInfo gives a distortion.
        camera: CameraIntrinsics of ``image_rgb`` from the CameraInfo with the same stamp
            (None if absent).
        ground_truth: {object name: [(rotation (3, 3), translation (3,) metres), ...]}.
        world_from_camera: (4, 4) the camera's pose in ``topics.FIXED_FRAME`` from the
            bag's /tf at the image's stamp (``write_bop_bag``), or None.
        scene: the static scene the frame belongs to ('scene_<id>'), or None.

    """

    stamp_ns: int
    frame_id: str
    image_rgb: np.ndarray
    camera: CameraIntrinsics | None = None
    ground_truth: dict = field(default_factory=dict)
    world_from_camera: np.ndarray | None = None
    scene: str | None = None


def bag_image_source(path: Path | str, image_topic: str = topics.IMAGE_TOPIC
                     ) -> tuple[str, str]:
    """
    Return (topic, transport) of the images of a bag: transport 'raw' or 'compressed'.

    The topic is ``image_topic`` when the bag holds it (an Image, or a CompressedImage
    when that topic is a compressed one), else image_transport's ``image_topic``/compressed
    when it holds that; raw is preferred (it is lossless) when both are there. A bag with
    neither gives (``image_topic``, 'raw'): no frames.
    """
    reader = _open(Path(path))
    try:
        return _image_source({c.topic: c.msgtype for c in reader.connections}, image_topic)
    finally:
        reader.close()


def read_bag_frames(path: Path | str, image_topic: str = topics.IMAGE_TOPIC,
                    camera_info_topic: str = topics.CAMERA_INFO_TOPIC) -> list[BagFrame]:
    """
    Read every image of a bag, paired by header stamp with CameraInfo and ground truth.

    Raw or compressed images (``bag_image_source`` chooses the topic); InputError names a
    frame whose image cannot be decoded.
    """
    path = Path(path)
    reader = _open(path)
    images, infos, poses = {}, {}, defaultdict(lambda: defaultdict(list))
    cameras, scenes = {}, {}
    try:
        image_topic, _ = _image_source({c.topic: c.msgtype for c in reader.connections},
                                       image_topic)
        for connection, _, raw in reader.messages():
            if connection.topic not in (image_topic, camera_info_topic, topics.TF_TOPIC,
                                        topics.SCENE_TOPIC) and \
                    topics.object_of_ground_truth_topic(connection.topic) is None:
                continue
            message = TYPESTORE.deserialize_cdr(raw, connection.msgtype)
            if connection.topic == topics.TF_TOPIC:
                for transform in message.transforms:
                    if transform.header.frame_id == topics.FIXED_FRAME:
                        cameras[(stamp_to_ns(transform.header.stamp), transform.child_frame_id)] \
                            = transform_matrix(transform.transform)
                continue
            if connection.topic == topics.SCENE_TOPIC:
                scenes[stamp_to_ns(message.stamp)] = message.frame_id
                continue
            stamp = stamp_to_ns(message.header.stamp)
            if connection.topic == image_topic:
                images[stamp] = message
            elif connection.topic == camera_info_topic:
                infos[stamp] = message
            else:
                name = topics.object_of_ground_truth_topic(connection.topic)
                poses[stamp][name].append(topics.pose_from_message(message))
    finally:
        reader.close()
    rectifier = Rectifier()
    frames = []
    for stamp in sorted(images):
        try:
            frames.append(dataclasses.replace(
                _frame(stamp, images[stamp], infos.get(stamp), poses.get(stamp, {}), rectifier),
                world_from_camera=cameras.get((stamp, images[stamp].header.frame_id)),
                scene=scenes.get(stamp)))
        except InputError as err:
            raise InputError(f'bag {path}, {image_topic} at stamp {stamp} ns: {err}') from err
    return frames


def _open(path):
    """Open a bag's Reader; InputError when it is missing or broken."""
    if not path.exists():
        raise InputError(f'bag not found: {path}')
    try:
        reader = Reader(path)
        reader.open()
    except Exception as err:  # rosbags raises its own error types for broken bags
        raise InputError(f'cannot open bag {path}: {err}') from err
    return reader


def _image_source(connections, image_topic):
    """(topic, transport) of the images among {topic: type} (see ``bag_image_source``)."""
    if connections.get(image_topic) == topics.IMAGE_TYPE:
        return image_topic, 'raw'
    if connections.get(image_topic) == topics.COMPRESSED_IMAGE_TYPE:
        return image_topic, 'compressed'
    compressed = topics.compressed_topic(image_topic)
    if connections.get(compressed) == topics.COMPRESSED_IMAGE_TYPE:
        return compressed, 'compressed'
    return image_topic, 'raw'


def _frame(stamp, image, info, poses, rectifier):
    if hasattr(image, 'format'):                    # sensor_msgs/CompressedImage
        rgb = decode_compressed(image.format, image.data)
    else:
        rgb = decode_image(image.height, image.width, image.encoding, image.step, image.data)
    height, width = rgb.shape[:2]
    if info is None:
        return BagFrame(stamp, image.header.frame_id, rgb, None, dict(poses))
    model = camera_model(info, width, height)
    return BagFrame(stamp, image.header.frame_id, rectifier(rgb, model), model.intrinsics,
                    dict(poses))
