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
Square crops around 2D boxes: the input of Q-Net.

Boxes are [u_min, v_min, u_max, v_max] in the OpenCV continuous pixel convention (pixel
centres at integers). A crop is square, centred on the box, of side ``context`` times the
box's longest side, so the aspect ratio is kept and some background stays around the object;
parts outside the image are filled with grey.
"""

import math

import cv2
import numpy as np
import numpy.typing as npt

FILL_VALUE = 128


def square_boxes(boxes_uv: npt.ArrayLike, context: float) -> np.ndarray:
    """(N, 4) square boxes of side ``context`` * longest side, centred on (N, 4) boxes."""
    boxes = np.asarray(boxes_uv, dtype=float).reshape(-1, 4)
    centre = (boxes[:, :2] + boxes[:, 2:]) * 0.5
    half = np.maximum((boxes[:, 2:] - boxes[:, :2]).max(axis=1) * (0.5 * context), 1.0)
    squares = np.empty_like(boxes)
    squares[:, :2] = centre - half[:, None]
    squares[:, 2:] = centre + half[:, None]
    return squares


def crop_pixels(u0: float, v0: float, u1: float, size: int) -> tuple[int, int, int, int]:
    """
    Return (x0, y0, side, factor): the pixels ``extract_crops`` cuts for a square.

    The square [u0, v0, u1, v0 + u1 - u0] (continuous pixels) becomes the whole-pixel region
    of columns x0 .. x0 + side - 1 and rows y0 .. y0 + side - 1, ``side`` a multiple of the
    integer area-averaging ``factor`` (1: none) that brings it to below twice ``size``.
    """
    factor = max(1, int((u1 - u0) // size))
    side = max(1, round((u1 - u0) / factor)) * factor
    x0 = math.floor((u0 + u1 - side) / 2.0 + 0.5)
    y0 = math.floor(v0 + (u1 - u0 - side) / 2.0 + 0.5)
    return x0, y0, side, factor


def extract_crops(image: np.ndarray, squares: npt.ArrayLike, size: int) -> np.ndarray:
    """
    Cut (N, 4) square regions out of an (H, W, 3) uint8 image, each resized to size x size.

    The region's edges are rounded to whole pixels (<= 0.5 px). A region more than twice
    ``size`` is first shrunk by area averaging with an integer factor (its side rounded to a
    multiple of the factor, <= 1 % of the side, centre kept): OpenCV's fast path, much
    cheaper than area averaging with a fractional factor. The remaining factor, below 2, is
    bilinear. Returns (N, size, size, 3) uint8.
    """
    squares = np.asarray(squares, dtype=float).reshape(-1, 4)
    height, width = image.shape[:2]
    crops = np.empty((len(squares), size, size, 3), dtype=np.uint8)
    # Python floats, not numpy scalars, for the per-crop arithmetic (numpy scalar
    # operations carry a per-call overhead that dominates such small computations).
    for k, (u0, v0, u1, _) in enumerate(squares.tolist()):
        x0, y0, side, factor = crop_pixels(u0, v0, u1, size)
        x1, y1 = x0 + side, y0 + side
        region = image[max(y0, 0):min(y1, height), max(x0, 0):min(x1, width)]
        if region.shape[0] != side or region.shape[1] != side:
            region = _padded(region, side, max(0, -y0), max(0, -x0))
        if factor > 1:
            region = cv2.resize(region, (side // factor, side // factor),
                                interpolation=cv2.INTER_AREA)
        cv2.resize(region, (size, size), dst=crops[k], interpolation=cv2.INTER_LINEAR)
    return crops


def _padded(region, side, top, left):
    """Place a partial region into a grey side x side canvas at (top, left)."""
    canvas = np.full((side, side, 3), FILL_VALUE, dtype=np.uint8)
    h, w = region.shape[:2]
    canvas[top:top + h, left:left + w] = region
    return canvas
