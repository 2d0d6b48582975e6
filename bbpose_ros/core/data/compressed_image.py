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
Decode and encode sensor_msgs/CompressedImage data (JPEG, PNG), without ROS imports.

The fields are image_transport's ``compressed`` transport's: ``format`` such as
'rgb8; jpeg compressed bgr8' (the camera's encoding; the codec; the channel order the
pixels were compressed in), 'mono8; png compressed mono8', or a bare 'jpeg' / 'png' (older
publishers); ``data`` the file's bytes. OpenCV writes colour as BGR, so the pixels are
taken as BGR unless the format says 'compressed rgb'. The node (its worker thread) and the
bag reader share ``decode_compressed``; every problem raises InputError naming the field.
"""

import array
import re
import struct

import cv2
import numpy as np
import numpy.typing as npt

from bbpose_ros.core.util.errors import InputError

CODECS = ('jpeg', 'png')
# image_transport's compressed publisher's default JPEG quality (its parameter jpeg_quality).
DEFAULT_JPEG_QUALITY = 95

_JPEG_START = b'\xff\xd8'
_JPEG_END = b'\xff\xd9'
_PNG_SIGNATURE = b'\x89PNG\r\n\x1a\n'
_PNG_END = b'IEND\xaeB`\x82'           # the IEND chunk's type and CRC: the file's last bytes
# JPEG start-of-frame markers (they hold the size): C0-CF but C4 (DHT), C8 (JPG), CC (DAC).
_JPEG_FRAME_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
# Zero bytes some camera encoders append after the end-of-image marker, at most this many.
_JPEG_PADDING = 1024

Data = bytes | bytearray | memoryview | array.array | np.ndarray


def codec_of(image_format: str) -> str:
    """
    Return the codec ('jpeg' or 'png') a CompressedImage ``format`` names.

    Raises InputError naming field format for a depth image (compressedDepth) or another
    codec.
    """
    text = image_format.lower()
    if 'compresseddepth' in text:
        raise InputError(f'compressed image format "{image_format}" is a depth image '
                         f'(compressedDepth) (field format); supported: colour or mono '
                         f'{" or ".join(CODECS)}')
    codec = text.rpartition(';')[2]
    if re.search(r'\bjpe?g\b', codec):
        return 'jpeg'
    if re.search(r'\bpng\b', codec):
        return 'png'
    raise InputError(f'unsupported compressed image format "{image_format}" (field format); '
                     f'supported: {", ".join(CODECS)} (image_transport compressed)')


def compressed_size(codec: str, data: Data) -> tuple[int, int]:
    """
    Return (width, height) in pixels from a JPEG's or PNG's header, without decoding.

    Raises InputError naming field data when the bytes are not such a file, or end before
    the size.
    """
    view = memoryview(np.frombuffer(data, dtype=np.uint8))
    start = _PNG_SIGNATURE if codec == 'png' else _JPEG_START
    if len(view) < len(start) and start.startswith(bytes(view)):
        raise InputError(f'{codec} data of {len(view)} bytes ends before its header (field '
                         f'data): truncated')
    if codec == 'png':
        if bytes(view[:8]) != _PNG_SIGNATURE:
            raise InputError(f'data is not a png image (field data): it starts with '
                             f'{bytes(view[:8]).hex(" ")}')
        if len(view) < 24 or bytes(view[12:16]) != b'IHDR':
            raise InputError(f'png data of {len(view)} bytes ends before its header (field '
                             f'data): truncated')
        return struct.unpack('>II', view[16:24])
    if bytes(view[:2]) != _JPEG_START:
        raise InputError(f'data is not a jpeg image (field data): it starts with '
                         f'{bytes(view[:8]).hex(" ")}')
    offset = 2
    while offset + 4 <= len(view) and view[offset] == 0xFF:
        marker = view[offset + 1]
        if marker == 0xFF:                                     # a fill byte
            offset += 1
            continue
        if marker in _JPEG_FRAME_MARKERS and offset + 9 <= len(view):
            height, width = struct.unpack('>HH', view[offset + 5:offset + 9])
            return width, height
        offset += 2 + struct.unpack('>H', view[offset + 2:offset + 4])[0]
    raise InputError(f'jpeg data of {len(view)} bytes holds no frame header (field data): '
                     f'truncated or corrupt')


def decode_compressed(image_format: str, data: Data,
                      max_pixels: int | None = None) -> np.ndarray:
    """
    Turn CompressedImage fields into an (H, W, 3) uint8 RGB array.

    ``format`` names the codec (JPEG or PNG) and the channel order (BGR unless it says
    'compressed rgb'); mono images come back grey in all three channels, an alpha channel is
    dropped. An image of more than ``max_pixels`` pixels (its header says) is refused
    before it is decoded. Raises InputError naming the field: an unsupported format, data
    that is not of the format's codec, truncated (no end marker) or corrupt, 16-bit pixels.
    """
    codec = codec_of(image_format)
    data = np.frombuffer(data, dtype=np.uint8)
    if data.size == 0:
        raise InputError('empty compressed image (field data)')
    width, height = compressed_size(codec, data)
    if width <= 0 or height <= 0:
        raise InputError(f'empty image: width={width}, height={height} in the {codec} '
                         f'header (field data)')
    if max_pixels is not None and width * height > max_pixels:
        raise InputError(f'image of {width}x{height} pixels, more than the limit of '
                         f'{max_pixels} (field data)')
    if not _ends_complete(codec, data):
        raise InputError(f'{codec} data of {data.size} bytes is truncated: no end-of-image '
                         f'marker (field data)')
    try:
        pixels = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    except cv2.error:
        pixels = None
    if pixels is None or pixels.shape[:2] != (height, width):
        raise InputError(f'{codec} data of {data.size} bytes cannot be decoded (field data): '
                         'corrupt')
    if pixels.dtype != np.uint8:
        raise InputError(f'{codec} image of {pixels.dtype.itemsize * 8}-bit pixels (field '
                         f'data); supported: 8-bit')
    return _to_rgb(pixels, 'compressed rgb' in image_format.lower())


def encode_compressed(image: npt.ArrayLike, codec: str = 'jpeg',
                      jpeg_quality: int = DEFAULT_JPEG_QUALITY) -> tuple[str, bytes]:
    """
    Return CompressedImage (format, data) of an (H, W, 3) uint8 RGB or (H, W) mono image.

    As image_transport's compressed publisher writes an rgb8 (mono8) camera: format
    'rgb8; jpeg compressed bgr8' ('mono8; jpeg compressed mono8'), or png. ``jpeg_quality``
    is 1 (smallest) .. 100 (best).
    """
    image = np.ascontiguousarray(image, dtype=np.uint8)
    if codec not in CODECS:
        raise InputError(f'unknown codec "{codec}"; choose one of {", ".join(CODECS)}')
    if not 1 <= jpeg_quality <= 100:
        raise InputError(f'jpeg quality {jpeg_quality} is not within 1 .. 100')
    if image.ndim == 2:
        encoding, order, pixels = 'mono8', 'mono8', image
    elif image.ndim == 3 and image.shape[2] == 3:
        encoding, order, pixels = 'rgb8', 'bgr8', cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    else:
        raise InputError(f'image of shape {image.shape}; expected (H, W, 3) RGB or (H, W)')
    options = [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)] if codec == 'jpeg' else []
    ok, data = cv2.imencode('.jpg' if codec == 'jpeg' else '.png', pixels, options)
    if not ok:
        raise InputError(f'OpenCV could not encode an image of shape {image.shape} as {codec}')
    return f'{encoding}; {codec} compressed {order}', data.tobytes()


def _ends_complete(codec, data):
    """Whether the data ends as a whole file does (JPEG: end marker, then only zeros)."""
    if codec == 'png':
        return data[-len(_PNG_END):].tobytes() == _PNG_END
    tail = data[-_JPEG_PADDING:].tobytes().rstrip(b'\x00')
    return tail.endswith(_JPEG_END)


def _to_rgb(pixels, rgb_order):
    """(H, W, 3) RGB of decoded pixels: grey, grey + alpha, three or four channels."""
    channels = 1 if pixels.ndim == 2 else pixels.shape[2]
    if channels == 1:
        return cv2.cvtColor(pixels.reshape(pixels.shape[:2]), cv2.COLOR_GRAY2RGB)
    if channels == 2:                                   # grey + alpha
        return cv2.cvtColor(np.ascontiguousarray(pixels[:, :, 0]), cv2.COLOR_GRAY2RGB)
    if channels == 4:
        return cv2.cvtColor(pixels, cv2.COLOR_RGBA2RGB if rgb_order else cv2.COLOR_BGRA2RGB)
    return np.ascontiguousarray(pixels) if rgb_order else cv2.cvtColor(pixels,
                                                                       cv2.COLOR_BGR2RGB)
