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

"""Write BOP frames into a rosbag2 (images, camera info and ground-truth poses)."""

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from tqdm import tqdm

from bbpose_ros.bags import topics
from bbpose_ros.core.data.bop import BopFrame
from bbpose_ros.core.data.image_encoding import encode_rgb8
from bbpose_ros.core.errors import InputError
from bbpose_ros.core.files import atomic_output
from bbpose_ros.core.geometry.camera import CameraIntrinsics

STORAGE = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}


def camera_info_message(stamp_ns: int, frame_id: str, camera: CameraIntrinsics) -> Any:
    """sensor_msgs/CameraInfo of an undistorted camera: K, P = [K | 0], D = 0, R = I."""
    types = topics.TYPESTORE.types
    roi = types['sensor_msgs/msg/RegionOfInterest'](
        x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return types[topics.CAMERA_INFO_TYPE](
        header=topics.header(stamp_ns, frame_id), height=camera.height, width=camera.width,
        distortion_model='plumb_bob', d=np.zeros(5), k=camera.k.reshape(-1),
        r=np.eye(3).reshape(-1), p=np.hstack([camera.k, np.zeros((3, 1))]).reshape(-1),
        binning_x=0, binning_y=0, roi=roi)


def image_message(stamp_ns: int, frame_id: str, image_rgb: np.ndarray) -> Any:
    """sensor_msgs/Image, rgb8, of an (H, W, 3) uint8 array."""
    height, width, encoding, step, data = encode_rgb8(image_rgb)
    return topics.TYPESTORE.types[topics.IMAGE_TYPE](
        header=topics.header(stamp_ns, frame_id), height=height, width=width,
        encoding=encoding, is_bigendian=0, step=step, data=data)


def write_bop_bag(frames: Sequence[BopFrame], out_path: Path | str, rate_hz: float = 10.0,
                  start_stamp_ns: int = 1_000_000_000, frame_id: str = topics.DEFAULT_FRAME_ID,
                  storage: str = 'mcap', min_visib: float = 0.1, progress: bool = True) -> int:
    """
    Write BOP frames as a rosbag2 at ``out_path``, atomically.

    Frame i is stamped start_stamp_ns + i / rate_hz. Per frame: an rgb8 Image, a CameraInfo
    with the same header, and a PoseStamped (metres) on /ground_truth/<object>/pose for each
    instance whose visible fraction is at least ``min_visib``. The bag is written to a
    temporary folder beside ``out_path`` and renamed when complete, so a failure leaves
    nothing behind. Returns the number of frames written.
    """
    out_path = Path(out_path)
    if storage not in STORAGE:
        raise InputError(f'unknown storage "{storage}"; choose one of {", ".join(STORAGE)}')
    if rate_hz <= 0:
        raise InputError(f'rate must be positive, got {rate_hz}')
    if out_path.exists():
        raise InputError(f'output already exists: {out_path}')
    if not frames:
        raise InputError('no frames to write')
    with atomic_output(out_path, keep_name=True) as staging:
        with Writer(staging, version=9, storage_plugin=STORAGE[storage]) as bag:
            _write_frames(bag, frames, rate_hz, start_stamp_ns, frame_id, min_visib, progress)
    return len(frames)


def _write_frames(writer, frames, rate_hz, start_stamp_ns, frame_id, min_visib, progress):
    typestore = topics.TYPESTORE
    image_conn = writer.add_connection(topics.IMAGE_TOPIC, topics.IMAGE_TYPE,
                                       typestore=typestore)
    info_conn = writer.add_connection(topics.CAMERA_INFO_TOPIC, topics.CAMERA_INFO_TYPE,
                                      typestore=typestore)
    pose_conns = {}
    for index, frame in enumerate(tqdm(frames, desc='writing bag', unit='frame',
                                       disable=not progress)):
        stamp = start_stamp_ns + int(round(index * 1e9 / rate_hz))
        image = frame.load_image()
        writer.write(image_conn, stamp, typestore.serialize_cdr(
            image_message(stamp, frame_id, image), topics.IMAGE_TYPE))
        writer.write(info_conn, stamp, typestore.serialize_cdr(
            camera_info_message(stamp, frame_id, frame.camera), topics.CAMERA_INFO_TYPE))
        for instance in frame.instances:
            if instance.visib_fract < min_visib:
                continue
            topic = topics.ground_truth_topic(instance.object_name)
            if topic not in pose_conns:
                pose_conns[topic] = writer.add_connection(topic, topics.POSE_TYPE,
                                                          typestore=typestore)
            message = topics.pose_message(stamp, frame_id, instance.rotation,
                                          instance.translation)
            writer.write(pose_conns[topic], stamp,
                         typestore.serialize_cdr(message, topics.POSE_TYPE))
