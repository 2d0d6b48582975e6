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
The colours beside each pose's projected contour, inside and outside it (numba).

``line_color_histograms`` counts the colour bins sampled along each line just inside and
just outside its contour point into a foreground and a background histogram per pose, and
keeps each line's samples for the local colour models. The per-pose loop runs in parallel
over the poses (``kernel_launch.use_threads``; launched under
``kernel_launch.parallel_launch``).

Pixel coordinates are continuous with pixel centres at integers, a sample at (u, v) reads
pixel (floor(u + 0.5), floor(v + 0.5)); the image is the flat (H * W,) array of its colour
bins (``color_histograms.color_bins``), row-major.
"""

import numba
import numpy as np

from bbpose_ros.core.refine.kernel_launch import KERNEL_FLAGS


@numba.njit(parallel=True, **KERNEL_FLAGS)
def line_color_histograms(bins, width, height, centres, normals, runs_f, runs_b, seen,
                          offsets, max_run, bin_count, samples, sample_counts):
    """
    Colour histograms on each pose's lines, inside and outside the contour.

    Returns:
        ((N, BINS) float64 inside, (N, BINS) outside: frequencies summing to 1, or all 0;
        (N, 2) int64 pixels counted inside and outside).

    Args:
        bins: (H * W,) uint16 colour bins of the image, row-major.
        width: image width, pixels.
        height: image height, pixels.
        centres: (N, P, 2) float64 projected contour points.
        normals: (N, P, 2) unit outward normals, taken in float32.
        runs_f: (N, P) pixels the silhouette continues inwards.
        runs_b: (N, P) pixels the background continues outwards.
        seen: (N, P) bool lines to count.
        offsets: (K,) float32 distances from the contour sampled, pixels.
        max_run: samples lie closer than min(run - 1, max_run) to the contour.
        bin_count: colour bins (BINS).
        samples: (N, P, 2, K) uint16 out: each line's sampled bins inside (0) and outside
            (1), in the order of ``offsets``, or (0, P, 2, K): not kept.
        sample_counts: (N, P, 2) int32 out: how many of them are set (with ``samples``).

    A sample at distance o reads pixel floor(centre + 0.5 -+ o * normal) (inside: minus),
    when it lies in the image.

    """
    count, lines = centres.shape[0], centres.shape[1]
    totals = np.zeros((count, 2), dtype=np.int64)
    hist_f = np.zeros((count, bin_count))
    hist_b = np.zeros((count, bin_count))
    keep = samples.shape[0] > 0
    for n in numba.prange(count):
        counts = np.zeros((2, bin_count), dtype=np.int32)
        for k in range(lines):
            if keep:
                sample_counts[n, k, 0] = sample_counts[n, k, 1] = 0
            if not seen[n, k]:
                continue
            start_u = np.float32(centres[n, k, 0] + 0.5)
            start_v = np.float32(centres[n, k, 1] + 0.5)
            for side in range(2):
                sign = np.float32(-1.0) if side == 0 else np.float32(1.0)
                reach = min((runs_f[n, k] if side == 0 else runs_b[n, k]) - 1.0, max_run)
                step_u = sign * np.float32(normals[n, k, 0])
                step_v = sign * np.float32(normals[n, k, 1])
                for offset in offsets:
                    if not offset < reach:
                        break
                    u = start_u + step_u * offset
                    v = start_v + step_v * offset
                    if not (u >= 0.0 and v >= 0.0 and u < width and v < height):
                        continue        # off the image (or not finite)
                    bin_ = bins[int(v) * width + int(u)]
                    counts[side, bin_] += 1
                    if keep:
                        samples[n, k, side, sample_counts[n, k, side]] = bin_
                        sample_counts[n, k, side] += 1
        totals[n, 0], totals[n, 1] = counts[0].sum(), counts[1].sum()
        for b in range(bin_count):
            if counts[0, b]:
                hist_f[n, b] = counts[0, b] / totals[n, 0]
            if counts[1, b]:
                hist_b[n, b] = counts[1, b] / totals[n, 1]
    return hist_f, hist_b, totals
