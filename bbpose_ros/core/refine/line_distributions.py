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
Where the contour lies on each correspondence line: its discrete distribution (numba).

``contour_distributions`` gives, along each line, the segments' foreground probabilities
from the colour model (one pair of histograms per pose, or a local model from the lines'
samples; and a predicted mask), then the discrete distribution of where the contour lies
on the line, its mean and variance. The per-pose loop runs in parallel over the poses
(``kernel_launch.use_threads``; launched under ``kernel_launch.parallel_launch``).

Pixel coordinates are continuous with pixel centres at integers, a sample at (u, v) reads
pixel (floor(u + 0.5), floor(v + 0.5)); the image is the flat (H * W,) array of its colour
bins (``color_histograms.color_bins``), row-major.
"""

import math

import numba
import numpy as np

from bbpose_ros.core.refine.kernel_launch import KERNEL_FLAGS


@numba.njit(**KERNEL_FLAGS)
def _mask_log_odds(mask_log_odds, squares, pose, col, row, outside):
    """Log-odds of the mask cell that pixel (col, row) falls in, ``outside`` beyond it."""
    size = mask_log_odds.shape[1]
    u0, v0 = squares[pose, 0], squares[pose, 1]
    cell = size / (squares[pose, 2] - u0)
    i = math.floor((col - u0) * cell)
    j = math.floor((row - v0) * cell)
    if i < 0 or i >= size or j < 0 or j >= size:
        return outside
    return mask_log_odds[pose, j, i]


@numba.njit(**KERNEL_FLAGS)
def _count_samples(samples, sample_counts, pose, line, counts, totals, sign):
    """Add (sign 1) or remove (-1) one line's colour samples to or from a window's counts."""
    for side in range(2):
        taken = sample_counts[pose, line, side]
        for i in range(taken):
            counts[side, samples[pose, line, side, i]] += sign
        totals[side] += sign * taken


@numba.njit(**KERNEL_FLAGS)
def _log_ratio(f, g, bound):
    """Return log(f / g) of two colour frequencies, within +-bound; 0 when both are 0."""
    if f == 0.0 and g == 0.0:
        return 0.0
    tiny = np.finfo(np.float64).tiny
    return min(max(math.log(f + tiny) - math.log(g + tiny), -bound), bound)


@numba.njit(**KERNEL_FLAGS)
def _line_pixel(bins, width, last_pixel, start_u, start_v, step_u, step_v, offset):
    """Return (column, row, colour bin) of the pixel ``offset`` along a line from its start."""
    # A valid line lies on the image (>= -0.5 before the shift, truncation rounds); the
    # guard only keeps a float32 rounding at the last pixel in.
    col = int(start_u + step_u * offset)
    row = int(start_v + step_v * offset)
    return col, row, bins[min(row * width + col, last_pixel)]


@numba.njit(**KERNEL_FLAGS)
def _sigmoid(log_odds):
    """Return the float32 probability of float32 log-odds (clipped to +-50 first)."""
    log_odds = min(max(log_odds, np.float32(-50.0)), np.float32(50.0))
    return np.float32(1.0) / (np.float32(1.0) + np.exp(-log_odds))


@numba.njit(parallel=True, **KERNEL_FLAGS)
def contour_distributions(bins, width, height, centres, normals, valid, hist_f, hist_b, scale,
                          segments, h_b, h_diff, positions, min_variance, max_log_ratio,
                          mask_log_odds, mask_squares, mask_weight, mask_outside,
                          samples, sample_counts, window, chunk, prior_pixels):
    """
    Where the contour lies on each line: (N, P) mean, (N, P) variance, (N, P, D) distribution.

    Args:
        bins: (H * W,) uint16 colour bins of the image, row-major.
        width: image width, pixels.
        height: image height, pixels.
        centres: (N, P, 2) float64 projected contour points (u, v).
        normals: (N, P, 2) unit outward normals (u, v), taken in float32.
        valid: (N, P) bool lines to evaluate; the others get the uniform distribution.
        hist_f: (N, BINS) float64 foreground colour histogram of each pose.
        hist_b: (N, BINS) float64 background colour histogram of each pose.
        scale: pixels per segment.
        segments: segments per line (the step function's length + D - 1).
        h_b: (F,) float32 the step function's background term.
        h_diff: (F,) float32 its foreground term minus the background one.
        positions: (D,) float64 contour positions, segments from the line's centre.
        min_variance: the variance's floor, segments squared.
        max_log_ratio: bound of a colour's foreground log-odds.
        mask_log_odds: (N, M, M) float32 per-pose mask log-odds, or (0, 1, 1): no masks.
        mask_squares: (N, 4) float64 each mask's square [u0, v0, u1, v1].
        mask_weight: float32 weight of the mask against the colours.
        mask_outside: float32 log-odds outside a mask's square.
        samples: (N, P, 2, S) uint16 colour bins sampled inside (0) and outside (1) each
            line's contour (``line_color_histograms``), or (0, P, 2, S): one colour model
            per pose (``hist_f``, ``hist_b``).
        sample_counts: (N, P, 2) int32 how many of each line's samples are set; all 0 for
            a pose: its global model.
        window: with samples, a line's colour model counts the samples of the lines up to
            this many places before and after it along the contour (the outline order).
        chunk: lines that share one window (it slides by this many lines).
        prior_pixels: the pose's global model counts as this many pixels of a local one,
            so that a window with few samples falls back to it.

    Line k of pose n samples, for segment s and pixel i, the point centre + (s * scale + i
    - half) * normal with half = (segments * scale - 1) / 2, in float32; a segment's
    foreground probability is the sigmoid of its pixels' summed log-odds.

    """
    count, lines = centres.shape[0], centres.shape[1]
    functions, distributions = h_b.shape[0], positions.shape[0]
    use_masks = mask_log_odds.shape[0] > 0
    keep = np.float32(1.0) - mask_weight
    half = (segments * scale - 1) / 2.0
    offsets = np.empty(segments * scale, dtype=np.float32)
    for i in range(segments * scale):
        offsets[i] = np.float32(i - half)
    mean = np.empty((count, lines))
    variance = np.empty((count, lines))
    distribution = np.empty((count, lines, distributions))
    bin_count = hist_f.shape[1]
    last_pixel = width * height - 1
    local = samples.shape[0] > 0
    direct = scale == 1 and not use_masks and not local
    # A window never holds a line twice: at most the whole contour.
    reach = max(min(window, (lines - chunk) // 2), 0)
    for n in numba.prange(count):
        seg_f = np.empty(segments, dtype=np.float32)
        # log(p_f / (1 - p_f)) with p_f = f / (f + b) per colour bin, clipped; 0 for a
        # colour neither histogram has seen (most of them: a histogram holds a few hundred).
        # Local models compute theirs from the window's counts. Segments of one pixel
        # (``direct``) read their bin's probability instead, computed when a line first
        # reads the bin: such lines read a few hundred bins, far fewer than the table has.
        log_ratio = np.empty(1 if direct or local else bin_count, dtype=np.float32)
        for b in range(0 if direct or local else bin_count):
            log_ratio[b] = _log_ratio(hist_f[n, b], hist_b[n, b], max_log_ratio)
        probability = np.empty(bin_count if direct else 1, dtype=np.float32)
        known = np.zeros(bin_count if direct else 1, dtype=np.bool_)
        # With local models: the window's pixel counts per bin, and its log-odds computed
        # when first read (stamped with the chunk they belong to).
        local_bins = bin_count if local else 1
        counts = np.zeros((2, local_bins), dtype=np.int32)
        local_ratio = np.empty(local_bins, dtype=np.float32)
        stamp = np.full(local_bins, -1, dtype=np.int64)
        totals = np.zeros(2, dtype=np.int64)
        low, high = -reach, -reach - 1         # lines in the window (unwrapped indices)
        inverse_f = inverse_b = 0.0
        for k in range(lines):
            if local and k % chunk == 0:
                new_low, new_high = k - reach, min(k + chunk, lines) - 1 + reach
                while high < new_high:
                    high += 1
                    _count_samples(samples, sample_counts, n, high % lines, counts, totals, 1)
                while low < new_low:
                    _count_samples(samples, sample_counts, n, low % lines, counts, totals, -1)
                    low += 1
                inverse_f = 1.0 / (totals[0] + prior_pixels)
                inverse_b = 1.0 / (totals[1] + prior_pixels)
            if not valid[n, k]:
                distribution[n, k, :] = 1.0 / distributions
                mean[n, k], variance[n, k] = 0.0, min_variance
                continue
            start_u = np.float32(centres[n, k, 0] + 0.5)
            start_v = np.float32(centres[n, k, 1] + 0.5)
            step_u, step_v = np.float32(normals[n, k, 0]), np.float32(normals[n, k, 1])
            if direct:      # one pixel a segment: its bin's probability, from the table
                for s in range(segments):
                    _, _, bin_ = _line_pixel(bins, width, last_pixel, start_u, start_v,
                                             step_u, step_v, offsets[s])
                    if not known[bin_]:
                        probability[bin_] = _sigmoid(np.float32(_log_ratio(
                            hist_f[n, bin_], hist_b[n, bin_], max_log_ratio)))
                        known[bin_] = True
                    seg_f[s] = probability[bin_]
            for s in range(0 if direct else segments):
                total = np.float32(0.0)
                for i in range(s * scale, (s + 1) * scale):
                    col, row, bin_ = _line_pixel(bins, width, last_pixel, start_u, start_v,
                                                 step_u, step_v, offsets[i])
                    if local:
                        if stamp[bin_] != k // chunk:
                            f = (counts[0, bin_] + prior_pixels * hist_f[n, bin_]) * inverse_f
                            g = (counts[1, bin_] + prior_pixels * hist_b[n, bin_]) * inverse_b
                            local_ratio[bin_] = _log_ratio(f, g, max_log_ratio)
                            stamp[bin_] = k // chunk
                        value = local_ratio[bin_]
                    else:
                        value = log_ratio[bin_]
                    if use_masks:
                        value = keep * value + mask_weight * _mask_log_odds(
                            mask_log_odds, mask_squares, n, col, row, mask_outside)
                    total += value
                seg_f[s] = _sigmoid(total)
            # p(contour at d) ~ prod_j (h_b[j] + seg_f[d + j] * h_diff[j]): each factor lies
            # in [h_b, h_f], bounded away from 0, so the product needs no logarithms.
            norm = 0.0
            for d in range(distributions):
                p = 1.0
                for j in range(functions):
                    p *= np.float64(h_b[j] + seg_f[d + j] * h_diff[j])
                distribution[n, k, d] = p
                norm += p
            first = second = 0.0
            for d in range(distributions):
                p = distribution[n, k, d] / norm
                distribution[n, k, d] = p
                first += p * positions[d]
                second += p * positions[d] * positions[d]
            mean[n, k] = first
            variance[n, k] = max(second - first * first, min_variance)
    return mean, variance, distribution
