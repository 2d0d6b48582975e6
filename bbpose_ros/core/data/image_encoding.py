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
Decode raw image buffers as sensor_msgs/Image lays them out, without ROS imports.

The functions take the message's plain fields, so the ROS node and the rosbag reader share
them; every problem raises InputError naming the field.
"""

import array

import cv2
import numpy as np
import numpy.typing as npt

from bbpose_ros.core.util.errors import InputError

# encoding -> (channels, conversion to RGB or None). A Bayer mosaic is named by its first
# 2x2 block in ROS and by the second row's pair in OpenCV (as cv_bridge maps them).
ENCODINGS = {
    'rgb8': (3, None),
    'bgr8': (3, cv2.COLOR_BGR2RGB),
    'rgba8': (4, cv2.COLOR_RGBA2RGB),
    'bgra8': (4, cv2.COLOR_BGRA2RGB),
    'mono8': (1, cv2.COLOR_GRAY2RGB),
    'bayer_rggb8': (1, cv2.COLOR_BayerBG2RGB),
    'bayer_bggr8': (1, cv2.COLOR_BayerRG2RGB),
    'bayer_gbrg8': (1, cv2.COLOR_BayerGR2RGB),
    'bayer_grbg8': (1, cv2.COLOR_BayerGB2RGB),
}


def decode_image(height: int, width: int, encoding: str, step: int,
                 data: bytes | bytearray | memoryview | array.array | np.ndarray,
                 max_pixels: int | None = None) -> np.ndarray:
    """
    Turn Image fields into an (height, width, 3) uint8 RGB array (a copy).

    Supports the 8-bit encodings in ENCODINGS (Bayer mosaics are demosaiced bilinearly);
    rows may be padded (step >= width * channels). An image of more than ``max_pixels``
    pixels is refused before anything is copied.
    """
    if encoding not in ENCODINGS:
        raise InputError(f'unsupported image encoding "{encoding}" (field encoding); '
                         f'supported: {", ".join(ENCODINGS)}')
    if height <= 0 or width <= 0:
        raise InputError(f'empty image: height={height}, width={width} (fields height, width)')
    if max_pixels is not None and height * width > max_pixels:
        raise InputError(f'image of {width}x{height} pixels, more than the limit of '
                         f'{max_pixels} (fields height, width)')
    channels, conversion = ENCODINGS[encoding]
    if step < width * channels:
        raise InputError(f'step {step} is smaller than width * channels = {width * channels} '
                         f'for {encoding} (field step)')
    buffer = np.frombuffer(data, dtype=np.uint8)
    if buffer.size != step * height:
        raise InputError(f'data has {buffer.size} bytes, expected step * height = '
                         f'{step * height} (field data)')
    pixels = buffer.reshape(height, step)[:, :width * channels].reshape(height, width, channels)
    if conversion is None:
        return np.ascontiguousarray(pixels)
    return cv2.cvtColor(pixels, conversion)


def encode_rgb8(image_rgb: npt.ArrayLike) -> tuple[int, int, str, int, np.ndarray]:
    """Fields (height, width, encoding, step, data) of an rgb8 Image for (H, W, 3) uint8."""
    image_rgb = np.ascontiguousarray(image_rgb, dtype=np.uint8)
    height, width = image_rgb.shape[:2]
    return height, width, 'rgb8', width * 3, image_rgb.reshape(-1)
