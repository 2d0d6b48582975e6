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

"""sensor_msgs/Image buffers -> RGB arrays: encodings, padding and the size limit."""

import numpy as np
import pytest

from bbpose_ros.core.data.image_encoding import decode_image
from bbpose_ros.core.util.errors import InputError

# Where each colour sits in the first 2x2 block of a ROS Bayer encoding.
BAYER = {'bayer_rggb8': 'RGGB', 'bayer_bggr8': 'BGGR', 'bayer_gbrg8': 'GBRG',
         'bayer_grbg8': 'GRBG'}


@pytest.fixture(scope='module')
def frame(lmo_frames):
    return lmo_frames[0].load_image()


def mosaic(rgb, pattern):
    """Sample an RGB image as a Bayer mosaic with the given 2x2 pattern."""
    out = np.zeros(rgb.shape[:2], np.uint8)
    for k, colour in enumerate(pattern):
        dy, dx = divmod(k, 2)
        out[dy::2, dx::2] = rgb[dy::2, dx::2, 'RGB'.index(colour)]
    return out


@pytest.mark.parametrize('encoding', list(BAYER))
def test_bayer_mosaics_come_back_in_their_colours(frame, encoding):
    raw = mosaic(frame, BAYER[encoding])
    height, width = raw.shape
    decoded = decode_image(height, width, encoding, width, raw.tobytes()).astype(int)
    error = np.abs(decoded - frame).mean()
    swapped = np.abs(decoded[:, :, ::-1] - frame).mean()     # red and blue exchanged
    assert error < 5.0 and swapped > 2 * error


def test_padded_rows_and_bgr8_decode_to_the_same_pixels(frame):
    height, width = frame.shape[:2]
    padded = np.zeros((height, width * 3 + 7), np.uint8)
    padded[:, :width * 3] = frame[:, :, ::-1].reshape(height, -1)
    decoded = decode_image(height, width, 'bgr8', width * 3 + 7, padded.tobytes())
    assert np.array_equal(decoded, frame)


def test_an_image_over_the_pixel_limit_is_refused_before_its_data_is_read():
    with pytest.raises(InputError, match='8192x8192 pixels, more than the limit of 1000'):
        decode_image(8192, 8192, 'rgb8', 8192 * 3, b'', max_pixels=1000)


@pytest.mark.parametrize('fields, words', [
    ((4, 4, '16UC1', 8, bytes(32)), 'field encoding'),
    ((4, 4, 'rgb8', 11, bytes(44)), 'field step'),
    ((4, 4, 'rgb8', 12, bytes(47)), 'field data'),
    ((0, 4, 'rgb8', 12, b''), 'fields height, width'),
])
def test_bad_fields_are_named(fields, words):
    with pytest.raises(InputError, match=words):
        decode_image(*fields)
