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
Axis-aligned 2D boxes [u_min, v_min, u_max, v_max] in continuous pixels.

Their centres, overlap and jitter, and the box of a mask.

Pixel convention of ``CameraIntrinsics``: the centre of pixel (col, row) is at
(u, v) = (col, row), so a box spanning whole pixels has edges on half-integers.
"""

import numpy as np
import numpy.typing as npt


def box_centres(boxes_uv: npt.ArrayLike) -> np.ndarray:
    """(N, 2) centres (u, v) of (N, 4) boxes [u_min, v_min, u_max, v_max]."""
    boxes = np.asarray(boxes_uv, dtype=float).reshape(-1, 4)
    return (boxes[:, :2] + boxes[:, 2:]) * 0.5


def box_iou(boxes_a: npt.ArrayLike, boxes_b: npt.ArrayLike) -> np.ndarray:
    """Intersection over union of (N, 4) and (M, 4) boxes [u_min, v_min, u_max, v_max]."""
    a = np.asarray(boxes_a, dtype=float).reshape(-1, 1, 4)
    b = np.asarray(boxes_b, dtype=float).reshape(1, -1, 4)
    inter = np.prod(np.clip(np.minimum(a[..., 2:], b[..., 2:])
                            - np.maximum(a[..., :2], b[..., :2]), 0.0, None), axis=-1)
    area_a = np.prod(a[..., 2:] - a[..., :2], axis=-1)
    area_b = np.prod(b[..., 2:] - b[..., :2], axis=-1)
    return inter / np.maximum(area_a + area_b - inter, 1e-12)


def jitter_boxes(boxes_uv: npt.ArrayLike, rng: np.random.Generator,
                 side_sigma: float) -> np.ndarray:
    """
    Move each side of (N, 4) boxes by N(0, side_sigma) times the box's width or height.

    This models a detector's amodal box errors: independent side errors give both centre
    shifts and size errors. Returns (N, 4) boxes, never narrower than 2 px.
    """
    boxes = np.asarray(boxes_uv, dtype=float)
    size = np.concatenate([boxes[:, 2:] - boxes[:, :2]] * 2, axis=1)
    jittered = boxes + rng.normal(0.0, 1.0, boxes.shape) * side_sigma * size
    centre = (jittered[:, :2] + jittered[:, 2:]) / 2
    half = np.maximum((jittered[:, 2:] - jittered[:, :2]) / 2, 1.0)
    return np.concatenate([centre - half, centre + half], axis=1)


def mask_box_uv(mask: np.ndarray) -> np.ndarray | None:
    """
    Compute the box (4,) [u_min, v_min, u_max, v_max] of the set pixels of an (H, W) mask.

    The outer edges of the extreme pixels, continuous pixels; None for an empty mask.
    """
    cols = np.flatnonzero(mask.any(axis=0))
    rows = np.flatnonzero(mask.any(axis=1))
    if len(cols) == 0:
        return None
    return np.array([cols[0] - 0.5, rows[0] - 0.5, cols[-1] + 0.5, rows[-1] + 0.5])
