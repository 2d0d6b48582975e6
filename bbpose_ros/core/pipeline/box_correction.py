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
The amodal box of a detection corrected from the dense net's amodal mask on its crop.

The detector's box comes from stride-8 features of a shrunk image; the dense net sees each
detection's crop at full resolution and predicts, per cell of an M x M grid over the crop's
square, the share of the cell the object's whole silhouette covers (its training target,
``synth.dense_targets``). Along a straight silhouette edge that share falls from 1 to 0 over
one cell and is 0.5 where the edge passes through a cell's centre, so each side is placed
where the share, interpolated linearly between cell centres, crosses 0.5: sub-cell, not on
the grid (exact where the edge passes a cell's centre or edge, within 1.5 - sqrt(2) of a
cell between). The box's four sides are the outermost such crossings of the column and row
profiles (the largest share in each column or row).

Box convention (``poses.Detection``, BOP's ``bbox_obj`` as ``data.bop.bop_box_to_uv``
reads it): the outer edges of the whole projected object, continuous pixels with pixel
centres at integers. The cells' frame is the crop's actual pixel region
(``crop_region``), whose edges are whole-pixel edges.

A side the mask cannot tell is the detector's: where the mask still covers the crop's
outermost cell (the object runs out of the crop), and the whole box where the mask is empty
or its box is implausibly far from the detector's (``MAX_SCALE``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
import math

import numpy as np
import numpy.typing as npt

from bbpose_ros.core.nets.crops import crop_pixels
from bbpose_ros.core.pipeline.poses import Detection

# The mask's share at a silhouette edge.
THRESHOLD = 0.5
# A mask box whose width or height differs from the detector's by more than this factor
# (either way) is not trusted: the detector's box is kept.
MAX_SCALE = 1.6


def crop_region(square_uv: npt.ArrayLike, size: int) -> np.ndarray:
    """
    Return the pixel region (4,) ``nets.crops.extract_crops`` cuts for a square.

    ``extract_crops`` cuts the whole pixels of ``crops.crop_pixels``; the crop's cells lie
    over that region, [u_min, v_min, u_max,
    v_max] in continuous pixels (edges on half-integers), not over the square asked for.
    """
    u0, v0, u1, _ = (float(value) for value in np.asarray(square_uv, dtype=float)[:4])
    x0, y0, side, _ = crop_pixels(u0, v0, u1, size)
    return np.array([x0 - 0.5, y0 - 0.5, x0 + side - 0.5, y0 + side - 0.5])


def _first_crossing(profile: np.ndarray, threshold: float) -> float:
    """
    Return where ``profile`` first rises to ``threshold``, in cell-centre index units.

    Linear between cell centres; NaN when it is already there at the first cell (the
    silhouette runs out of the grid) or never gets there.
    """
    above = np.flatnonzero(profile >= threshold)
    if len(above) == 0 or above[0] == 0:
        return math.nan
    j = int(above[0])
    low, high = float(profile[j - 1]), float(profile[j])
    return j - 1 + (threshold - low) / max(high - low, 1e-9)


def mask_box_cells(probability: npt.ArrayLike, threshold: float = THRESHOLD) -> np.ndarray:
    """
    Return the sub-cell box (4,) [x_min, y_min, x_max, y_max] of an (M, M) amodal share map.

    In cell units from the grid's top-left corner (cell (i, j) spans [j, j + 1] x [i, i + 1];
    row i is y). Each side is where the column (row) profile of largest shares crosses
    ``threshold``, interpolated between cell centres; NaN for a side where the mask reaches
    the grid's edge, all NaN for a mask nowhere at ``threshold``.
    """
    share = np.asarray(probability, dtype=float)
    columns, rows = share.max(axis=0), share.max(axis=1)
    size_x, size_y = len(columns), len(rows)
    return np.array([_first_crossing(columns, threshold) + 0.5,
                     _first_crossing(rows, threshold) + 0.5,
                     size_x - 0.5 - _first_crossing(columns[::-1], threshold),
                     size_y - 0.5 - _first_crossing(rows[::-1], threshold)])


def mask_box_uv(probability: npt.ArrayLike, region_uv: npt.ArrayLike,
                threshold: float = THRESHOLD) -> np.ndarray:
    """
    Return ``mask_box_cells`` in full-frame continuous pixels, for a grid over ``region_uv``.

    Args:
        probability: (M, M) amodal share per cell.
        region_uv: (4,) the crop's pixel region [u_min, v_min, u_max, v_max] (square).
        threshold: the share at the edge.

    Returns:
        (4,) [u_min, v_min, u_max, v_max], NaN where the mask cannot tell a side.

    """
    region = np.asarray(region_uv, dtype=float)
    share = np.asarray(probability, dtype=float)
    cells = mask_box_cells(share, threshold)
    scale = (region[2:] - region[:2]) / np.array(share.shape[::-1], dtype=float)
    return np.concatenate([region[:2] + cells[:2] * scale, region[:2] + cells[2:] * scale])


def corrected_box(detector_uv: npt.ArrayLike, probability: npt.ArrayLike,
                  region_uv: npt.ArrayLike, threshold: float = THRESHOLD) -> np.ndarray:
    """
    Return a detection's amodal box (4,) corrected by its amodal mask.

    Each side the mask tells replaces the detector's; the others stay the detector's. The
    detector's box is returned whole when the mask's box is empty, inverted or scaled by
    more than ``MAX_SCALE`` from the detector's in width or height.
    """
    detector = np.asarray(detector_uv, dtype=float)
    mask = mask_box_uv(probability, region_uv, threshold)
    box = np.where(np.isfinite(mask), mask, detector)
    size, reference = box[2:] - box[:2], detector[2:] - detector[:2]
    if not np.all(size > 0) or np.any(size > MAX_SCALE * reference) or \
            np.any(size * MAX_SCALE < reference):
        return detector
    return box


def corrected_detections(detections: Sequence[Detection], amodal: npt.ArrayLike,
                         squares_uv: npt.ArrayLike, crop_size: int,
                         threshold: float = THRESHOLD) -> list[Detection]:
    """
    Return the detections with their boxes corrected by the dense net's amodal masks.

    Args:
        detections: a frame's detections, in the order of the maps.
        amodal: (N, M, M) amodal share per cell (``DenseMaps.amodal``).
        squares_uv: (N, 4) the crops' squares (``DenseMaps.squares_uv``).
        crop_size: side of the crops in pixels (``DenseConfig.crop_size``).
        threshold: the share at the edge.

    Returns:
        New Detections (object and score kept) in the same order.

    """
    return [replace(d, box_uv=corrected_box(d.box_uv, share, crop_region(square, crop_size),
                                            threshold))
            for d, share, square in zip(detections, amodal, squares_uv)]
