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

"""Pinhole camera intrinsics and projection (CameraInfo is read by ``camera_info``)."""

from dataclasses import dataclass
from typing import Self

import numpy as np
import numpy.typing as npt

from bbpose_ros.core.util.errors import InputError


@dataclass(frozen=True)
class CameraIntrinsics:
    """
    A pinhole camera in OpenCV's continuous pixel convention.

    A point (x, y, z) in the camera optical frame (x right, y down, z forward) projects to
    u = fx * x / z + cx, v = fy * y / z + cy. The centre of pixel (col, row) sits at
    (u, v) = (col, row), so the image spans u in [-0.5, width - 0.5].
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        values = np.array([self.fx, self.fy, self.cx, self.cy], dtype=float)
        if not np.all(np.isfinite(values)) or self.fx <= 0.0 or self.fy <= 0.0:
            raise InputError(
                f'invalid camera intrinsics: fx={self.fx}, fy={self.fy}, cx={self.cx}, '
                f'cy={self.cy} (focal lengths must be finite and positive)')
        if self.width <= 0 or self.height <= 0:
            raise InputError(f'invalid image size {self.width}x{self.height}')

    @classmethod
    def from_k(cls, k: npt.ArrayLike, width: int, height: int) -> Self:
        """Build from a 3x3 (or row-major 9-element) camera matrix K."""
        k = np.asarray(k, dtype=float).reshape(3, 3)
        return cls(float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2]),
                   int(width), int(height))

    @classmethod
    def from_p(cls, p: npt.ArrayLike, width: int, height: int) -> Self:
        """Build from a 3x4 (or row-major 12-element) projection matrix P (rectified images)."""
        p = np.asarray(p, dtype=float).reshape(3, 4)
        return cls.from_k(p[:, :3], width, height)

    @property
    def k(self) -> np.ndarray:
        """Return the 3x3 camera matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def scaled(self, width: int, height: int) -> 'CameraIntrinsics':
        """
        Intrinsics of the same camera whose image was resized to width x height.

        Pixel edges scale, pixel centres do not: c' = (c + 0.5) * s - 0.5.
        """
        sx, sy = width / self.width, height / self.height
        return CameraIntrinsics(self.fx * sx, self.fy * sy, (self.cx + 0.5) * sx - 0.5,
                                (self.cy + 0.5) * sy - 0.5, int(width), int(height))

    def cropped(self, square_uv: npt.ArrayLike, size: int) -> 'CameraIntrinsics':
        """
        Intrinsics of the region ``square_uv`` resized to a size x size image.

        ``square_uv`` is [u_min, v_min, u_max, v_max] (square, continuous pixels; its edges
        become the crop's pixel edges): u' = (u - u_min) * s - 0.5 with s = size / side.
        """
        u_min, v_min, u_max, _ = (float(x) for x in square_uv)
        scale = size / (u_max - u_min)
        return CameraIntrinsics(self.fx * scale, self.fy * scale,
                                (self.cx - u_min) * scale - 0.5,
                                (self.cy - v_min) * scale - 0.5, int(size), int(size))

    def pixel_map_to(self, other: 'CameraIntrinsics') -> np.ndarray:
        """
        Return the (2, 3) affine map from this camera's pixels to ``other``'s (same frame).

        The ray through (u, v) here meets ``other``'s image at (fx'/fx (u - cx) + cx',
        fy'/fy (v - cy) + cy'): exact for two pinhole cameras at one pose, so an image
        resampled with it (``cv2.warpAffine``) is what ``other`` sees, and a box maps to a
        box.
        """
        sx, sy = other.fx / self.fx, other.fy / self.fy
        return np.array([[sx, 0.0, other.cx - sx * self.cx], [0.0, sy, other.cy - sy * self.cy]])

    def project(self, points_cam: npt.ArrayLike) -> np.ndarray:
        """Project (..., 3) points in the camera frame (metres) to (..., 2) pixels (u, v)."""
        points_cam = np.asarray(points_cam, dtype=float)
        z = points_cam[..., 2]
        return np.stack([self.fx * points_cam[..., 0] / z + self.cx,
                         self.fy * points_cam[..., 1] / z + self.cy], axis=-1)

    def normalized(self, uv: npt.ArrayLike) -> np.ndarray:
        """Map (..., 2) pixels (u, v) to normalised image coordinates ((u-cx)/fx, (v-cy)/fy)."""
        return (np.asarray(uv, dtype=float) - (self.cx, self.cy)) / (self.fx, self.fy)

    def rays(self, uv: npt.ArrayLike) -> np.ndarray:
        """Return the viewing ray (x/z, y/z, 1), camera frame, of each pixel: (..., 3)."""
        xy = self.normalized(uv)
        return np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1)
