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
OpenGL's clip-space matrix of a camera, in the pixel convention of the ground truth.

Pixel coordinates are continuous and follow ``CameraIntrinsics``: the centre of pixel
(col, row) is at (u, v) = (col, row), so pixel (col, row) spans [col - 0.5, col + 0.5] x
[row - 0.5, row + 0.5]. Points at a pose and their pixel boxes: ``geometry.projection``.
"""

import numpy as np
import numpy.typing as npt

from bbpose_ros.core.geometry.camera import CameraIntrinsics


def opengl_projection(camera: CameraIntrinsics, near: float, far: float,
                      origin: tuple[float, float] = (0, 0),
                      size: tuple[int, int] | None = None) -> np.ndarray:
    """
    Build the (4, 4) OpenGL projection of an OpenCV camera, for a window onto its image.

    The window is ``size`` = (width, height) pixels (default the whole image) whose first
    pixel is image pixel ``origin`` = (col, row). Camera coordinates are OpenCV's (x right,
    y down, z forward, metres); ``near`` and ``far`` (metres) bound the depth range. GL puts
    pixel centres at window coordinate i + 0.5 while OpenCV puts them at i, hence the
    ``c + 0.5`` below. Image row 0 maps to window row 0, so ``glReadPixels`` returns the rows
    top first and no flip is needed.
    """
    width, height = size if size is not None else (camera.width, camera.height)
    cx = camera.cx - origin[0] + 0.5
    cy = camera.cy - origin[1] + 0.5
    return np.array([
        [2.0 * camera.fx / width, 0.0, 2.0 * cx / width - 1.0, 0.0],
        [0.0, 2.0 * camera.fy / height, 2.0 * cy / height - 1.0, 0.0],
        [0.0, 0.0, (far + near) / (far - near), -2.0 * far * near / (far - near)],
        [0.0, 0.0, 1.0, 0.0],
    ])


def gl_matrix(matrix: npt.ArrayLike) -> bytes:
    """Return the bytes of a square matrix in GL's column-major float32 layout."""
    return np.ascontiguousarray(np.asarray(matrix, dtype=np.float32).T).tobytes()
