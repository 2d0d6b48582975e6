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
The one reader of sensor_msgs/CameraInfo: K, D, R, P, binning and ROI -> a CameraModel.

``camera_model`` reduces a CameraInfo to what the pipeline needs for images of one size:
the pinhole intrinsics of the image it sees and, for a distorted (or rotated) raw image,
how to rectify it. Distortion is handled by rectifying the image, with maps made once per
CameraInfo change (``Rectifier``): the detector, Q-Net's crops and the Bounding Box Equation
all assume a pinhole image, and rectifying boxes and points alone would leave the crops
distorted. Supported models: plumb_bob, rational_polynomial (OpenCV's radial-tangential)
and equidistant (OpenCV's fisheye). As in image_geometry, the rectified image is the
camera P describes (poses are in its frame, rotated by R from the raw camera's), ROI
offsets are applied first, binning second; unlike image_geometry, binning and resizing keep
pixel centres exact (c' = (c + 0.5) / b - 0.5, image_geometry uses c / b: a 0.25 px
difference at binning 2).

``info`` may be any object with CameraInfo's fields (an rclpy or a rosbags message), so
the core needs no ROS import.
"""

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.util.errors import InputError

# distortion_model -> the numbers of coefficients it takes in field d
DISTORTION_MODELS = {'plumb_bob': (4, 5), 'rational_polynomial': (8,), 'equidistant': (4,)}
# How far (pixels, any element) P[:3, :3] may be from K where the two must agree.
PK_TOLERANCE_PX = 1.0


@dataclass(frozen=True)
class CameraModel:
    """
    A CameraInfo reduced to one image size: the intrinsics the pipeline uses, how to rectify.

    Attributes:
        intrinsics: pinhole CameraIntrinsics of the image the pipeline sees (the raw image
            when it needs no rectification, otherwise the rectified one).
        distortion_model: '' when the image needs no rectification, else the model of
            ``d`` ('plumb_bob' also stands for a rotation ``r`` without distortion).
        raw_k: row-major 3x3 K of the raw image, in its pixels (with rectification).
        d: the distortion coefficients (with rectification).
        r: row-major 3x3 rotation from the raw camera to the rectified one (with
            rectification).

    Frozen and made of tuples: equal CameraInfos give equal models, the key of the
    Rectifier's cached maps.

    """

    intrinsics: CameraIntrinsics
    distortion_model: str = ''
    raw_k: tuple[float, ...] = ()
    d: tuple[float, ...] = ()
    r: tuple[float, ...] = ()

    @property
    def needs_rectification(self) -> bool:
        """Return whether images must be rectified before the pipeline sees them."""
        return bool(self.distortion_model)

    def rectification_maps(self) -> tuple[np.ndarray, np.ndarray]:
        """Return the fixed-point (cv2.remap) maps from the rectified image to the raw one."""
        camera = self.intrinsics
        k, r = np.reshape(self.raw_k, (3, 3)), np.reshape(self.r, (3, 3))
        make = (cv2.fisheye.initUndistortRectifyMap if self.distortion_model == 'equidistant'
                else cv2.initUndistortRectifyMap)
        return make(k, np.array(self.d), r, camera.k, (camera.width, camera.height),
                    cv2.CV_16SC2)


class Rectifier:
    """
    Rectifies images as their CameraModel says, with maps made once per model.

    Keeps the maps of the last model only: a camera's CameraInfo rarely changes. Not
    thread-safe; give each thread its own.
    """

    def __init__(self) -> None:
        self._model = None
        self._maps = None

    def __call__(self, image: np.ndarray, model: CameraModel) -> np.ndarray:
        """Return ``image`` rectified (bilinear, black outside the raw image), or itself."""
        if not model.needs_rectification:
            return image
        if model != self._model:
            self._maps, self._model = model.rectification_maps(), model
        return cv2.remap(image, *self._maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)


def camera_model(info: Any, width: int, height: int, rectified: bool = False) -> CameraModel:
    """
    Make the CameraModel of a sensor_msgs/CameraInfo for images of width x height pixels.

    ``rectified``: the images are rectified already (P[:3, :3] describes them; D and R are
    not used). Otherwise a raw image with a non-zero D or a rotation R is rectified to the
    camera of P (of K when P is all zero), and one without either uses K.

    The CameraInfo's image is its ROI (all zero: the full width x height) reduced by the
    binning (0: 1). When the image differs from that size by a common factor (a resized
    stream) the intrinsics are scaled to it. Every problem is an InputError naming the
    field: a matrix all zero, not finite, or with a focal length <= 0; D not finite, of a
    model not supported, or of the wrong length; P[:3, :3] and K more than PK_TOLERANCE_PX
    apart where they must agree (no distortion, no rotation); an image of another aspect
    ratio; an ROI outside the image.
    """
    k = _matrix(info.k, 'k', 3, 3)
    p = _matrix(info.p, 'p', 3, 4)[:, :3]
    r = _matrix(info.r, 'r', 3, 3)
    d = np.asarray(info.d, dtype=float).ravel()
    if not np.all(np.isfinite(d)):
        raise InputError(f'camera_info field d holds {_non_finite(d)}')
    rotated = np.any(r) and not np.allclose(r, np.eye(3), atol=1e-9)
    distorted = bool(np.any(d))
    rectify = not rectified and (distorted or rotated)
    if rectify and distorted:
        _check_distortion(info.distortion_model, d)
    name, target = ('p', p) if rectified or (rectify and np.any(p)) else ('k', k)
    if not rectified:
        _check_focal('k', k)
    _check_focal(name, target)
    if np.any(p) and not distorted and not rotated and np.abs(p - k).max() > PK_TOLERANCE_PX:
        raise InputError(f'camera_info fields k and p disagree (P[:3, :3] - K up to '
                         f'{np.abs(p - k).max():.2f} px) though d is zero and r the identity: '
                         f'which one describes the image is unknown')
    reduce = _Reduction(info, width, height)
    intrinsics = CameraIntrinsics.from_k(reduce(target), width, height)
    if not rectify:
        return CameraModel(intrinsics)
    return CameraModel(intrinsics, info.distortion_model if distorted else 'plumb_bob',
                       tuple(reduce(k).ravel()), tuple(d) if distorted else (0.0,) * 5,
                       tuple(r.ravel()) if rotated else tuple(np.eye(3).ravel()))


class _Reduction:
    """
    Maps a full-resolution camera matrix to the pixels of the image at hand.

    The ROI offset first, then the binning, then the resize of a resized stream; each keeps
    pixel centres exact.
    """

    def __init__(self, info, width, height):
        full_w, full_h = info.width or width, info.height or height
        roi = info.roi
        x, y = roi.x_offset, roi.y_offset
        roi_w, roi_h = roi.width or full_w - x, roi.height or full_h - y
        if x + roi_w > full_w or y + roi_h > full_h:
            raise InputError(f'camera_info field roi ({x}, {y}, {roi_w}x{roi_h}) does not fit '
                             f'in fields width, height = {full_w}x{full_h}')
        self.offset = (x, y)
        self.binning = (info.binning_x or 1, info.binning_y or 1)
        expected_w, expected_h = roi_w // self.binning[0], roi_h // self.binning[1]
        if expected_w < 1 or expected_h < 1:
            raise InputError(f'camera_info fields binning_x, binning_y = {self.binning} leave '
                             f'no pixel of the {roi_w}x{roi_h} image')
        self.scale = (width / expected_w, height / expected_h)
        if abs(self.scale[0] - self.scale[1]) > 1.0 / min(expected_w, expected_h):
            raise InputError(f'image of {width}x{height} pixels, but camera_info fields width, '
                             f'height, roi and binning say {expected_w}x{expected_h} (another '
                             f'aspect ratio, not a resized stream)')

    def __call__(self, matrix: npt.ArrayLike) -> np.ndarray:
        """Return the 3x3 camera matrix in the image's pixels (no skew)."""
        matrix = np.asarray(matrix, dtype=float)
        out = np.eye(3)
        for axis in (0, 1):
            factor = self.scale[axis] / self.binning[axis]
            centre = matrix[axis, 2] - self.offset[axis]
            out[axis, axis] = matrix[axis, axis] * factor
            out[axis, 2] = (centre + 0.5) * factor - 0.5
        return out


def _matrix(values, name, rows, cols):
    """Return a CameraInfo matrix field as a (rows, cols) array; InputError if malformed."""
    matrix = np.asarray(values, dtype=float)
    if matrix.size != rows * cols:
        raise InputError(f'camera_info field {name} holds {matrix.size} numbers, not '
                         f'{rows * cols}')
    if not np.all(np.isfinite(matrix)):
        raise InputError(f'camera_info field {name} holds {_non_finite(matrix)}')
    return matrix.reshape(rows, cols)


def _non_finite(values):
    return ' and '.join(sorted({str(v) for v in np.ravel(values) if not np.isfinite(v)}))


def _check_focal(name, matrix):
    if not np.any(matrix):
        raise InputError(f'camera_info field {name} is all zero')
    if matrix[0, 0] <= 0.0 or matrix[1, 1] <= 0.0:
        raise InputError(f'camera_info field {name}: focal lengths fx={matrix[0, 0]}, '
                         f'fy={matrix[1, 1]} must be positive')


def _check_distortion(model, d):
    if model not in DISTORTION_MODELS:
        raise InputError(f'camera_info field distortion_model "{model}" (with a non-zero d) '
                         f'is not supported; supported: {", ".join(DISTORTION_MODELS)}')
    if len(d) not in DISTORTION_MODELS[model]:
        raise InputError(f'camera_info field d holds {len(d)} coefficients; {model} takes '
                         f'{" or ".join(map(str, DISTORTION_MODELS[model]))}')
