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
Dense targets of a rendered crop at the dense head's resolution: coordinates and masks.

The renderer gives, per render pixel, the model coordinates of the surface seen there; the
head predicts an (M, M) grid over the same square. Cell (i, j) of the grid covers render
pixels [i c, (i + 1) c) x [j c, (j + 1) c), c = R / M, and its centre is the centre of that
block. Its coordinate target is the value at the cell centre: the mean of the (one or four)
render pixels around it when they all show the target (exact for a planar patch), else the
mean over the target's pixels of the cell. Its mask targets are the shares of the cell that
show the target (visible) and that the target's whole silhouette covers (amodal).

Coordinates are normalised by the model's axis-aligned box (``geometry.dense_grid``).
"""

import numpy as np

from bbpose_ros.core.util.errors import InputError


def dense_targets(model_coordinates: np.ndarray, visible: np.ndarray, amodal: np.ndarray,
                  size: int, box_min: np.ndarray,
                  box_size: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Reduce one render's target maps to the (size, size) grid of the dense head.

    Args:
        model_coordinates: (R, R, 3) model coordinates (metres) per render pixel.
        visible: (R, R) bool, render pixels where the target is the front-most surface.
        amodal: (R, R) bool, the target's whole (unoccluded) silhouette.
        size: grid side M; R must be a multiple of it.
        box_min: (3,) the model box's minimum corner (``dense_grid.model_box``), metres.
        box_size: (3,) the model box's size, metres.

    Returns:
        (M, M, 3) float32 normalised coordinates (0 where no target pixel), (M, M) float32
        visible share and (M, M) float32 amodal share of each cell.

    """
    render = visible.shape[0]
    if visible.shape != (render, render) or render % size:
        raise InputError(f'a {visible.shape} render does not reduce to a {size}x{size} grid')
    cell = render // size
    blocks = visible.reshape(size, cell, size, cell).transpose(0, 2, 1, 3)
    coords = model_coordinates.reshape(size, cell, size, cell, 3).transpose(0, 2, 1, 3, 4)
    weights = blocks.astype(np.float32)
    count = weights.sum(axis=(2, 3))
    mean = np.einsum('ijab,ijabk->ijk', weights, coords) / np.maximum(count, 1)[..., None]
    centre = slice((cell - 1) // 2, cell // 2 + 1)
    core = blocks[:, :, centre, centre]
    at_centre = coords[:, :, centre, centre].mean(axis=(2, 3))
    whole_core = core.all(axis=(2, 3))
    values = np.where(whole_core[..., None], at_centre, mean)
    normalised = (values - box_min) / box_size
    normalised[count == 0] = 0.0
    amodal_share = amodal.reshape(size, cell, size, cell).mean(axis=(1, 3))
    return (normalised.astype(np.float32), (count / cell ** 2).astype(np.float32),
            amodal_share.astype(np.float32))
