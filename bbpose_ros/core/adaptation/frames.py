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
The unlabelled frames adaptation learns from: a BOP folder's images or a rosbag's.

A frame is named by ``key`` ('<scene_id>/<image_id>' for a BOP folder, '<stamp_ns>' for a
bag) and fingerprinted by the SHA-256 of its decoded pixels (``image_fingerprint``), so
that the frames a network adapted on are recognised wherever they are read from again (a
copied folder, the bag the images were written to) and ``bbpose eval`` can refuse to score
them.
"""

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bbpose_ros.core.data.bop import BopDataset
from bbpose_ros.core.data.fingerprints import sha256_of_arrays
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.util.errors import InputError


@dataclass(frozen=True)
class RecordedFrame:
    """
    One unlabelled frame.

    Attributes:
        key: its name in the recording ('<scene_id>/<image_id>' or '<stamp_ns>').
        camera: CameraIntrinsics of the (rectified) image.
        read: returns the (H, W, 3) uint8 RGB image (read from disk or held in memory).
        world_from_camera: (4, 4) the camera's pose in the recording's fixed frame (BOP's
            ``cam_R_w2c`` / ``cam_t_w2c``, a bag's /tf), or None.
        scene: the static scene the frame belongs to (its objects stay put), or None.

    """

    key: str
    camera: CameraIntrinsics
    read: Callable[[], np.ndarray]
    world_from_camera: np.ndarray | None = None
    scene: str | None = None


def image_fingerprint(image_rgb: np.ndarray) -> str:
    """Return the SHA-256 hex digest of an (H, W, 3) uint8 image's pixels and shape."""
    image = np.asarray(image_rgb, dtype=np.uint8)
    return sha256_of_arrays(image, text=str(image.shape))


def dataset_frames(root: Path | str, split: str = 'test') -> list[RecordedFrame]:
    """
    Return the images of a BOP folder's split, sorted by scene and image id; no ground truth read.

    Raises:
        InputError: a missing folder or split, or a split without images.

    """
    frames = BopDataset(root, split).frames(ground_truth=False)
    if not frames:
        raise InputError(f'no images in {Path(root) / split}')
    return [RecordedFrame(f'{f.scene_id}/{f.image_id}', f.camera, f.load_image,
                          f.world_from_camera, str(f.scene_id)) for f in frames]


def bag_frames(frames: Sequence, image_topic: str) -> list[RecordedFrame]:
    """
    Return the recorded frames of a bag's images (``bags.reader.BagFrame``), in stamp order.

    Raises:
        InputError: no images, or an image without a CameraInfo of the same stamp.

    """
    if not frames:
        raise InputError(f'the bag has no images on {image_topic}')
    missing = [f.stamp_ns for f in frames if f.camera is None]
    if missing:
        raise InputError(f'{len(missing)} image(s) on {image_topic} have no camera_info of '
                         f'the same stamp (first: {missing[0]} ns); record both topics')
    return [RecordedFrame(str(f.stamp_ns), f.camera, lambda f=f: f.image_rgb,
                          getattr(f, 'world_from_camera', None), getattr(f, 'scene', None))
            for f in frames]
