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
Write rosbag2 files: raw CDR messages (``write_bag``), or BOP frames (``write_bop_bag``).

Every bag is written through ``write_bag``, with the one typestore (``bags.typestore``).
"""

from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
import shutil
from typing import Any

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from tqdm import tqdm

from bbpose_ros.bags import topics
from bbpose_ros.bags.typestore import add_missing_types, TYPESTORE
from bbpose_ros.core.data.bop import BopFrame
from bbpose_ros.core.data.compressed_image import DEFAULT_JPEG_QUALITY, encode_compressed
from bbpose_ros.core.data.image_encoding import encode_rgb8
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.core.util.files import atomic_output

STORAGE = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}

BagMessage = tuple[str, str, int, bytes]   # topic, type name, log time (ns), raw CDR


def camera_info_message(stamp_ns: int, frame_id: str, camera: CameraIntrinsics) -> Any:
    """sensor_msgs/CameraInfo of an undistorted camera: K, P = [K | 0], D = 0, R = I."""
    types = TYPESTORE.types
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
    return TYPESTORE.types[topics.IMAGE_TYPE](
        header=topics.header(stamp_ns, frame_id), height=height, width=width,
        encoding=encoding, is_bigendian=0, step=step, data=data)


def compressed_image_message(stamp_ns: int, frame_id: str, image_rgb: np.ndarray,
                             jpeg_quality: int = DEFAULT_JPEG_QUALITY) -> Any:
    """
    sensor_msgs/CompressedImage of an (H, W, 3) uint8 RGB array, as image_transport sends it.

    JPEG of quality ``jpeg_quality`` (1 .. 100), format 'rgb8; jpeg compressed bgr8'.
    """
    image_format, data = encode_compressed(image_rgb, 'jpeg', jpeg_quality)
    return TYPESTORE.types[topics.COMPRESSED_IMAGE_TYPE](
        header=topics.header(stamp_ns, frame_id), format=image_format,
        data=np.frombuffer(data, dtype=np.uint8))


def write_bag(path: Path | str, messages: Iterable[BagMessage], storage: str = 'mcap',
              replace: bool = False) -> int:
    """
    Write raw CDR messages as a rosbag2 at ``path``, atomically; return how many.

    A topic's connection is made at its first message, with the type that message names
    (types rosbags lacks are added to the typestore from their installed definitions). The
    bag is written to a temporary folder beside ``path`` and renamed when complete, so a
    failure leaves nothing behind. An existing path is an InputError, but with ``replace``
    an existing bag (a folder with metadata.yaml), which is removed first.
    """
    path = Path(path)
    _check_output(path, storage, replace)
    if path.exists():
        shutil.rmtree(path)
    count = 0
    with atomic_output(path, keep_name=True) as staging:
        with Writer(staging, version=9, storage_plugin=STORAGE[storage]) as bag:
            connections = {}
            for topic, msgtype, time_ns, raw in messages:
                if topic not in connections:
                    add_missing_types([msgtype])
                    connections[topic] = bag.add_connection(topic, msgtype,
                                                            typestore=TYPESTORE)
                bag.write(connections[topic], time_ns, raw)
                count += 1
    return count


def write_bop_bag(frames: Sequence[BopFrame], out_path: Path | str, rate_hz: float = 10.0,
                  start_stamp_ns: int = 1_000_000_000, frame_id: str = topics.DEFAULT_FRAME_ID,
                  storage: str = 'mcap', min_visib: float = 0.1, progress: bool = True,
                  compressed: bool = False, jpeg_quality: int = DEFAULT_JPEG_QUALITY) -> int:
    """
    Write BOP frames as a rosbag2 at ``out_path``, atomically (``write_bag``).

    Frame i is stamped start_stamp_ns + i / rate_hz. Per frame: an rgb8 Image on
    /camera/image_raw (with ``compressed``, instead a JPEG CompressedImage of quality
    ``jpeg_quality`` on /camera/image_raw/compressed, as image_transport's compressed
    transport records it), a CameraInfo with the same header, and a PoseStamped (metres) on
    /ground_truth/<object>/pose for each instance whose visible fraction is at least
    ``min_visib``. A frame with a camera pose (``BopFrame.world_from_camera``) has it on /tf
    first (world -> ``frame_id``, as a robot's TF), with its scene on /ground_truth/scene (a
    std_msgs/Header, frame_id 'scene_<id>'). Returns the number of frames written.
    """
    out_path = Path(out_path)
    _check_output(out_path, storage, replace=False)
    if rate_hz <= 0:
        raise InputError(f'rate must be positive, got {rate_hz}')
    if not 1 <= jpeg_quality <= 100:
        raise InputError(f'jpeg quality must be within 1 .. 100, got {jpeg_quality}')
    if not frames:
        raise InputError('no frames to write')
    if compressed:
        image = (topics.compressed_topic(topics.IMAGE_TOPIC), topics.COMPRESSED_IMAGE_TYPE,
                 lambda stamp, rgb: compressed_image_message(stamp, frame_id, rgb,
                                                             jpeg_quality))
    else:
        image = (topics.IMAGE_TOPIC, topics.IMAGE_TYPE,
                 lambda stamp, rgb: image_message(stamp, frame_id, rgb))
    write_bag(out_path, _bop_messages(frames, rate_hz, start_stamp_ns, frame_id, min_visib,
                                      progress, image), storage)
    return len(frames)


def _check_output(path: Path, storage: str, replace: bool) -> None:
    if storage not in STORAGE:
        raise InputError(f'unknown storage "{storage}"; choose one of {", ".join(STORAGE)}')
    if path.exists() and not replace:
        raise InputError(f'output already exists: {path}')
    if path.exists() and not (path / 'metadata.yaml').is_file():
        raise InputError(f'{path} exists and is not a bag; not replacing it')


def _bop_messages(frames: Sequence[BopFrame], rate_hz: float, start_stamp_ns: int,
                  frame_id: str, min_visib: float, progress: bool,
                  image: tuple[str, str, Callable[[int, np.ndarray], Any]]
                  ) -> Iterator[BagMessage]:
    """Yield the messages of ``write_bop_bag``; ``image``: (topic, type, message maker)."""
    image_topic, image_type, image_of = image
    for index, frame in enumerate(tqdm(frames, desc='writing bag', unit='frame',
                                       disable=not progress)):
        stamp = start_stamp_ns + int(round(index * 1e9 / rate_hz))
        if frame.world_from_camera is not None:     # before the image: there when it is
            yield _serialized(topics.SCENE_TOPIC, topics.SCENE_TYPE, stamp,
                              topics.header(stamp, f'scene_{frame.scene_id}'))
            yield _serialized(topics.TF_TOPIC, topics.TF_TYPE, stamp, topics.transform_message(
                stamp, topics.FIXED_FRAME, frame_id, frame.world_from_camera))
        yield _serialized(image_topic, image_type, stamp, image_of(stamp, frame.load_image()))
        yield _serialized(topics.CAMERA_INFO_TOPIC, topics.CAMERA_INFO_TYPE, stamp,
                          camera_info_message(stamp, frame_id, frame.camera))
        for instance in frame.instances:
            if instance.visib_fract >= min_visib:
                yield _serialized(topics.ground_truth_topic(instance.object_name),
                                  topics.POSE_TYPE, stamp,
                                  topics.pose_message(stamp, frame_id, instance.rotation,
                                                      instance.translation))


def _serialized(topic: str, msgtype: str, stamp_ns: int, message: Any) -> BagMessage:
    return topic, msgtype, stamp_ns, TYPESTORE.serialize_cdr(message, msgtype).tobytes()
