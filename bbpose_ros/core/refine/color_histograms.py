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
    """(...) histogram bin of each (..., 3) uint8 RGB colour."""
    colors = colors_rgb.astype(np.int32) >> _SHIFT
    return (colors[..., 0] * BINS_PER_CHANNEL + colors[..., 1]) * BINS_PER_CHANNEL \
        + colors[..., 2]


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

    @classmethod
    def from_colors(cls, foreground_rgb: np.ndarray,
                    background_rgb: np.ndarray) -> ColorHistograms:
        """Histograms of (N, 3) and (M, 3) uint8 colour samples."""
        return cls(_frequencies(foreground_rgb), _frequencies(background_rgb))

    def blended(self, other: ColorHistograms, rate: float) -> ColorHistograms:
        """(1 - rate) * self + rate * other: how a track learns its colours over frames."""
        return ColorHistograms((1.0 - rate) * self.foreground + rate * other.foreground,
                               (1.0 - rate) * self.background + rate * other.background)

    def log_posteriors(self, floor: float = 1e-4) -> tuple[np.ndarray, np.ndarray]:
        """
        Per bin, log p(foreground | colour) and log p(background | colour).

        Unseen colours get 0.5 each; posteriors are kept within [floor, 1 - floor] so that
        one pixel cannot veto a whole line. Index the arrays with ``color_bins``.
        """
        total = self.foreground + self.background
        p_f = np.where(total > 0.0, self.foreground / np.where(total > 0.0, total, 1.0), 0.5)
        p_f = np.clip(p_f, floor, 1.0 - floor)
        return np.log(p_f), np.log1p(-p_f)


def _frequencies(colors_rgb):
    counts = np.bincount(color_bins(np.asarray(colors_rgb).reshape(-1, 3)),
                         minlength=BINS_PER_CHANNEL ** 3).astype(float)
    total = counts.sum()
    return counts / total if total > 0 else counts
