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
Predicted silhouette masks as the region modality's foreground model.

A dense net predicts, over each detection's square crop, the probability that a cell shows
the object (``nets.dense``: visible and amodal masks on an M x M grid). Along the
correspondence lines these probabilities can stand in for, or mix with, the colour
histograms' foreground probability: a mask does not mistake an occluder or a clutter of
the object's colours for the object, and the amodal one keeps the whole projected
silhouette where an occluder hides part of it.

Grid convention (``geometry.dense_grid``): a mask covers its square ``square_uv`` (full-frame
continuous pixels, the crop's pixel edges); cell (row j, column i) covers
[u0 + i s, u0 + (i + 1) s] x [v0 + j s, v0 + (j + 1) s] with s = side / M.
"""

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

# Log-odds of foreground outside a mask's square (the crop holds the whole object).
OUTSIDE_LOG_ODDS = -4.0
# Probabilities are clipped to [EPSILON, 1 - EPSILON] before their log-odds.
EPSILON = 1e-3


@dataclass(frozen=True)
class ForegroundMasks:
    """
    Per pose, a predicted foreground mask over a square of the image.

    Attributes:
        probabilities: (N, M, M) foreground probability of each cell, 0..1.
        squares_uv: (N, 4) each mask's square [u0, v0, u1, v1], full-frame pixels.

    """

    probabilities: np.ndarray
    squares_uv: np.ndarray

    @cached_property
    def log_odds_grid(self) -> np.ndarray:
        """(N, M, M) float32 log-odds of the cells, made once for all iterations."""
        p = np.clip(self.probabilities, EPSILON, 1.0 - EPSILON)
        return np.log(p / (1.0 - p)).astype(np.float32)

    def take(self, indices: Sequence[int]) -> 'ForegroundMasks':
        """Return the masks of the given poses, in that order."""
        indices = np.asarray(indices, dtype=np.int64)
        return ForegroundMasks(self.probabilities[indices], self.squares_uv[indices])
