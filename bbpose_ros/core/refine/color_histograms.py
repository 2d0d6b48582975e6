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

"""Foreground and background colour statistics of one object: two RGB histograms."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

BINS_PER_CHANNEL = 16
_SHIFT = 4                  # 256 / BINS_PER_CHANNEL = 2 ** _SHIFT


def color_bins(colors_rgb: np.ndarray) -> np.ndarray:
    """(...) uint16 histogram bin of each (..., 3) uint8 RGB colour (an image: (H, W))."""
    coarse = (np.asarray(colors_rgb) >> _SHIFT).astype(np.uint16)
    return (coarse[..., 0] << 2 * _SHIFT) | (coarse[..., 1] << _SHIFT) | coarse[..., 2]


@dataclass
class ColorHistograms:
    """
    Normalised RGB histograms of the object (foreground) and its surroundings (background).

    Attributes:
        foreground: (BINS_PER_CHANNEL ** 3,) frequencies summing to 1 (or all 0: unknown).
        background: the same for the background.

    """

    foreground: np.ndarray
    background: np.ndarray

    def blended(self, other: ColorHistograms, rate: float) -> ColorHistograms:
        """(1 - rate) * self + rate * other: how a track learns its colours over frames."""
        return ColorHistograms((1.0 - rate) * self.foreground + rate * other.foreground,
                               (1.0 - rate) * self.background + rate * other.background)
