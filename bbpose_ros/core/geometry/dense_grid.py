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
The dense maps' grid and coordinate normalisation, shared by their targets and their use.

A crop's dense maps are an M x M grid over its square (``square_uv``, full-frame continuous
pixels, whose edges are the crop's pixel edges as in ``CameraIntrinsics.cropped``). Model
coordinates are normalised by the model's axis-aligned box: ``c = (x - box_min) /
box_size``, so the model's points lie in [0, 1]^3.
"""

import numpy as np
import numpy.typing as npt


def model_box(vertices: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """(3,) minimum and (3,) size (metres) of the axis-aligned box of (V, 3) model points."""
    vertices = np.asarray(vertices, dtype=np.float64)
    low = vertices.min(axis=0)
    return low, vertices.max(axis=0) - low


def cell_centres_uv(square_uv: npt.ArrayLike, size: int) -> np.ndarray:
    """(M, M, 2) full-frame pixels (u, v) of the centres of a crop's M x M grid cells."""
    square_uv = np.asarray(square_uv, dtype=float)
    steps = (np.arange(size) + 0.5) * ((square_uv[2] - square_uv[0]) / size)
    return np.stack(np.meshgrid(square_uv[0] + steps, square_uv[1] + steps), axis=-1)
