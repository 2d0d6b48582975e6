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
Compressed cameras: sensor_msgs/CompressedImage (JPEG, PNG) decoded, in bags and the node.

LM-O frames compressed as image_transport's compressed publisher does, decoded back by
``decode_compressed``; bad data refused naming the field.
"""

import cv2
import numpy as np
import pytest

from bbpose_ros.core.data.compressed_image import codec_of, compressed_size
from bbpose_ros.core.data.compressed_image import decode_compressed, encode_compressed
from bbpose_ros.core.errors import InputError

# Mean absolute difference per channel (grey levels, 0..255) of a quality-95 JPEG of an LM-O
# frame against the frame: a few tenths measured; swapped channels are off by over 10.
JPEG_TOLERANCE = 2.0


@pytest.fixture(scope='module')
def frame(lmo_frames):
    return lmo_frames[0].load_image()


def error(decoded, original):
    return np.abs(decoded.astype(float) - original).mean()


def test_png_comes_back_bit_exact(frame):
    image_format, data = encode_compressed(frame, 'png')
    assert image_format == 'rgb8; png compressed bgr8'
    assert np.array_equal(decode_compressed(image_format, data), frame)


def test_jpeg_comes_back_close_in_its_colours(frame):
    image_format, data = encode_compressed(frame, 'jpeg')
    assert image_format == 'rgb8; jpeg compressed bgr8'
    decoded = decode_compressed(image_format, data)
    assert decoded.shape == frame.shape and decoded.dtype == np.uint8
    assert error(decoded, frame) < JPEG_TOLERANCE
    assert error(decoded[:, :, ::-1], frame) > 5 * JPEG_TOLERANCE
    smaller = encode_compressed(frame, 'jpeg', jpeg_quality=50)[1]
    assert len(smaller) < len(data)


def test_mono_comes_back_grey_in_three_channels(frame):
    grey = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)
    for codec in ('jpeg', 'png'):
        image_format, data = encode_compressed(grey, codec)
        assert image_format == f'mono8; {codec} compressed mono8'
        decoded = decode_compressed(image_format, data)
        assert decoded.shape == frame.shape
        assert np.array_equal(decoded[:, :, 0], decoded[:, :, 2])
        assert error(decoded[:, :, 0], grey) < (JPEG_TOLERANCE if codec == 'jpeg' else 1e-9)


def test_channel_order_follows_the_format(frame):
    # A publisher that compressed RGB pixels says so; a bare 'png' is OpenCV's BGR.
    ok, data = cv2.imencode('.png', frame)          # RGB pixels written as they are
    assert ok
    assert np.array_equal(decode_compressed('rgb8; png compressed rgb8', data), frame)
    assert np.array_equal(decode_compressed('png', data)[:, :, ::-1], frame)
    ok, data = cv2.imencode('.png', cv2.cvtColor(frame, cv2.COLOR_RGB2BGRA))
    assert np.array_equal(decode_compressed('bgra8; png compressed bgra8', data), frame)


@pytest.mark.parametrize('codec', ['jpeg', 'png'])
def test_truncated_data_is_refused_naming_it(frame, codec):
    image_format, data = encode_compressed(frame, codec)
    for size in (len(data) - 1, len(data) // 2, 30, 3):
        with pytest.raises(InputError, match=r'truncated.*\(field data\)|\(field data\).*'
                                             'truncated'):
            decode_compressed(image_format, data[:size])


def test_bad_data_and_formats_are_refused_naming_the_field(frame):
    jpeg_format, jpeg = encode_compressed(frame, 'jpeg')
    png_format, png = encode_compressed(frame, 'png')
    middle = len(png) // 2
    cases = [
        (jpeg_format, b'', r'empty compressed image \(field data\)'),
        (jpeg_format, png, r'data is not a jpeg image \(field data\)'),
        (png_format, jpeg, r'data is not a png image \(field data\)'),
        (png_format, png[:middle] + bytes(1000) + png[middle + 1000:],
         r'cannot be decoded \(field data\): corrupt'),
        ('16UC1; compressedDepth png', png, r'compressedDepth\) \(field format\)'),
        ('rgb8; tiff compressed bgr8', png, r'unsupported compressed image format '
                                            r'"rgb8; tiff compressed bgr8" \(field format\)'),
    ]
    for image_format, data, pattern in cases:
        with pytest.raises(InputError, match=pattern):
            decode_compressed(image_format, data)
    ok, sixteen = cv2.imencode('.png', frame.astype(np.uint16) * 256)
    assert ok
    with pytest.raises(InputError, match=r'16-bit pixels \(field data\)'):
        decode_compressed('rgb16; png compressed bgr16', sixteen)


def test_an_image_over_the_pixel_limit_is_refused_before_decoding(frame):
    image_format, data = encode_compressed(frame, 'jpeg')
    assert compressed_size('jpeg', data) == (640, 480)
    assert compressed_size('png', encode_compressed(frame, 'png')[1]) == (640, 480)
    with pytest.raises(InputError, match=r'640x480 pixels, more than the limit of 1000'):
        decode_compressed(image_format, data, max_pixels=1000)
    assert decode_compressed(image_format, data, max_pixels=640 * 480).shape == frame.shape


def test_codec_names_as_publishers_write_them():
    assert codec_of('rgb8; jpeg compressed bgr8') == 'jpeg'
    assert codec_of('bgr8; png compressed bgr8') == 'png'
    assert codec_of('jpeg') == 'jpeg' and codec_of('JPG') == 'jpeg' and codec_of('png') == 'png'
