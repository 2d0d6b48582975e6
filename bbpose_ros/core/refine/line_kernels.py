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
The region modality's per-line loops, compiled with numba.

Every correspondence iteration walks each of a few thousand lines pixel by pixel; as numpy
broadcasts that took many large temporary arrays a call, so these loops run compiled
(``numba.njit``, cached on disk after the first compilation) and touch each pixel once.
``region_modality`` owns the method; these kernels only evaluate it:

* ``closest_views``: the stored view nearest to each pose's camera direction;
* ``project_contours``: the contour points of each pose's closest view, projected;
* ``hide_occluded``: contour points that another instance's silhouette, nearer the
  camera, covers;
* ``contour_distributions``: along each line, the segments' foreground probabilities from
  the colour model (and a predicted mask), then the discrete distribution of where the
  contour lies on the line, its mean and variance;
* ``line_color_histograms``: the colour histograms just inside and outside each contour
  (and, for local colour models, each line's samples);
* ``gradient_hessian``: each pose's Gauss-Newton gradient and Hessian from its lines.

Conventions are the modality's: pixel coordinates continuous with pixel centres at
integers, a sample at (u, v) reads pixel (floor(u + 0.5), floor(v + 0.5)); the image is the
flat (H * W,) array of its colour bins, row-major. The per-pose loops run in parallel over
the poses (``use_threads``).

Threads wait for work asleep, not spinning (``OMP_WAIT_POLICY=PASSIVE`` unless the
environment sets it, before numba starts its OpenMP threads): on a robot's two cores the
other processes (DDS, the camera driver) then keep their core, and a spinning worker does not
slow the refinement down when that core is busy.

Two threads may refine at once (stream mode: the tracks in the foreground, the full
pipeline beside them). numba's OpenMP and TBB threading layers take parallel kernels
launched from several threads at once; its 'workqueue' layer (the one left where neither
library loads) aborts the process on such a launch, so there the parallel kernels are
launched one at a time (``parallel_launch``).
"""

import contextlib
import math
import os
import threading

import numba
import numpy as np

os.environ.setdefault('OMP_WAIT_POLICY', 'PASSIVE')

# Fast-math without 'nnan' / 'ninf': the colour loops test for NaN coordinates.
_NUMBA = {'cache': True, 'nogil': True, 'error_model': 'numpy',
          'fastmath': {'nsz', 'arcp', 'contract', 'afn', 'reassoc'}}


def use_threads(count: int) -> None:
    """Run this thread's kernels on ``count`` threads (0: one per core, numba's default)."""
    numba.set_num_threads(min(count, numba.config.NUMBA_NUM_THREADS) if count > 0
                          else numba.config.NUMBA_NUM_THREADS)


_LAUNCHES = threading.Lock()
_CONCURRENT_LAYERS = ('omp', 'tbb')
_concurrent: bool | None = None     # known once a parallel kernel has run


def concurrent_launches_safe() -> bool:
    """Tell whether numba's threading layer takes parallel kernels from several threads."""
    global _concurrent
    if _concurrent is None:
        try:
            layer = numba.threading_layer()
        except ValueError:      # no parallel kernel has run yet: the layer is not chosen
            return False
        _concurrent = layer in _CONCURRENT_LAYERS
    return _concurrent


def parallel_launch() -> contextlib.AbstractContextManager:
    """Return what a parallel kernel's launch runs under: a shared lock where it must."""
    return contextlib.nullcontext() if concurrent_launches_safe() else _LAUNCHES


@numba.njit(**_NUMBA)
def _closest_view(view_directions, rotation, translation):
    """Index of the view direction nearest to the camera's, -R^T t, seen from the model."""
    dx = -(rotation[0, 0] * translation[0] + rotation[1, 0] * translation[1]
           + rotation[2, 0] * translation[2])
    dy = -(rotation[0, 1] * translation[0] + rotation[1, 1] * translation[1]
           + rotation[2, 1] * translation[2])
    dz = -(rotation[0, 2] * translation[0] + rotation[1, 2] * translation[1]
           + rotation[2, 2] * translation[2])
    best, best_dot = 0, -np.inf
    for view in range(view_directions.shape[0]):
        dot = (dx * view_directions[view, 0] + dy * view_directions[view, 1]
               + dz * view_directions[view, 2])
        if dot > best_dot:
            best, best_dot = view, dot
    return best


@numba.njit(**_NUMBA)
def closest_views(view_directions, rotations, translations):
    """
    Per pose, the index of the stored view nearest to the camera's direction.

    Args:
        view_directions: (V, 3) unit vectors from the model origin towards the camera.
        rotations: (N, 3, 3) model-to-camera rotations.
        translations: (N, 3) translations (any unit).

    Returns:
        (N,) int64 view indices (the first of equally near ones).

    """
    views = np.empty(rotations.shape[0], dtype=np.int64)
    for n in range(rotations.shape[0]):
        views[n] = _closest_view(view_directions, rotations[n], translations[n])
    return views


@numba.njit(**_NUMBA)
def project_contours(view_directions, view_points, view_normals, view_runs_f, view_runs_b,
                     poses, rotation, translation, fx, fy, cx, cy, points, centres, normals,
                     runs_f, runs_b, in_front):
    """
    Project the contour of one object's closest view at each of its poses, into the outputs.

    Args:
        view_directions: (V, 3) the viewpoint model's view directions.
        view_points: (V, P, 3) float32 the viewpoint model's contour points, model frame.
        view_normals: (V, P, 3) float32 their outward normals, model frame.
        view_runs_f: (V, P) float32 how far the silhouette continues inwards, metres.
        view_runs_b: (V, P) float32 how far the background continues outwards, metres.
        poses: (M,) which of the N poses are the object's.
        rotation: (N, 3, 3) model-to-camera rotations of all poses.
        translation: (N, 3) their translations, metres.
        fx: focal length in u, pixels.
        fy: focal length in v, pixels.
        cx: principal point u, pixels.
        cy: principal point v, pixels.
        points: (N, P, 3) float32 out: the views' contour points, model frame.
        centres: (N, P, 2) float64 out: projected (u, v); in front or not.
        normals: (N, P, 2) float64 out: unit 2D normals (u, v).
        runs_f: (N, P) float64 out: the inward run length in pixels at the point's depth.
        runs_b: (N, P) float64 out: the outward one.
        in_front: (N, P) bool out: depth > 1e-6 m.

    """
    lines = view_points.shape[1]
    for m in range(poses.shape[0]):
        n = poses[m]
        r, t = rotation[n], translation[n]
        view = _closest_view(view_directions, r, t)
        for k in range(lines):
            point, normal = view_points[view, k], view_normals[view, k]
            px, py, pz = point[0], point[1], point[2]
            points[n, k, :] = point
            x = r[0, 0] * px + r[0, 1] * py + r[0, 2] * pz + t[0]
            y = r[1, 0] * px + r[1, 1] * py + r[1, 2] * pz + t[1]
            z = r[2, 0] * px + r[2, 1] * py + r[2, 2] * pz + t[2]
            in_front[n, k] = z > 1e-6
            if not z > 1e-6:
                z = 1e-6
            centres[n, k, 0] = fx * x / z + cx
            centres[n, k, 1] = fy * y / z + cy
            nx, ny, nz = normal[0], normal[1], normal[2]
            nu = r[0, 0] * nx + r[0, 1] * ny + r[0, 2] * nz
            nv = r[1, 0] * nx + r[1, 1] * ny + r[1, 2] * nz
            norm = max(math.sqrt(nu * nu + nv * nv), 1e-9)
            normals[n, k, 0], normals[n, k, 1] = nu / norm, nv / norm
            px_per_m = fx / z
            runs_f[n, k] = view_runs_f[view, k] * px_per_m
            runs_b[n, k] = view_runs_b[view, k] * px_per_m


# Horizontal bands an occluder's outline is cut into: a point's inside test reads only the
# edges that cross its band.
OUTLINE_BANDS = 64


@numba.njit(**_NUMBA)
def _outline_bands(polygon, v_low, per_band, bands):
    """
    Index a closed (P, 2) outline's edges by the horizontal bands of rows they span.

    A row v lies in band min(int((v - v_low) * per_band), bands - 1), the expression
    ``hide_occluded`` places its points by; edge i joins vertex i - 1 (the last for i = 0)
    to vertex i and is listed in the bands of its two ends' rows and those between. An edge
    a point crosses (min(v_i, v_j) <= v < max(v_i, v_j)) is therefore listed in the point's
    band: the expression never reverses the order of two rows.

    Returns:
        ((bands + 1,) int64 starts, (E,) int64 edges): band b's edges are
        ``edges[starts[b]:starts[b + 1]]``.

    """
    points = polygon.shape[0]
    first, last = np.empty(points, dtype=np.int64), np.empty(points, dtype=np.int64)
    starts = np.zeros(bands + 1, dtype=np.int64)
    previous = points - 1
    for i in range(points):
        v_i, v_j = polygon[i, 1], polygon[previous, 1]
        first[i] = min(int((min(v_i, v_j) - v_low) * per_band), bands - 1)
        last[i] = min(int((max(v_i, v_j) - v_low) * per_band), bands - 1)
        for b in range(first[i], last[i] + 1):
            starts[b + 1] += 1
        previous = i
    for b in range(bands):
        starts[b + 1] += starts[b]
    edges = np.empty(starts[bands], dtype=np.int64)
    fill = starts[:bands].copy()
    for i in range(points):
        for b in range(first[i], last[i] + 1):
            edges[fill[b]] = i
            fill[b] += 1
    return starts, edges


@numba.njit(**_NUMBA)
def _inside_outline(u, v, polygon, band, starts, edges):
    """Tell whether (u, v) lies inside an outline (even-odd rule), by its band's edges."""
    inside = False
    points = polygon.shape[0]
    for e in range(starts[band], starts[band + 1]):
        i = edges[e]
        j = i - 1 if i > 0 else points - 1
        u_i, v_i, u_j, v_j = polygon[i, 0], polygon[i, 1], polygon[j, 0], polygon[j, 1]
        if (v_i > v) != (v_j > v) and u < (u_j - u_i) * (v - v_i) / (v_j - v_i) + u_i:
            inside = not inside
    return inside


@numba.njit(**_NUMBA)
def hide_occluded(centres, depths, instances, casts, in_front):
    """
    Mark the contour points that a nearer instance's silhouette covers as not seen.

    A pose's projected contour, in the order it was traced, is its silhouette's outline;
    where a pose of another instance, nearer the camera by its origin's depth, covers a
    contour point of this one, the image shows the occluder there, not this contour.

    Args:
        centres: (N, P, 2) projected contour points, pixels, in outline order.
        depths: (N,) depth of each pose's model origin, metres.
        instances: (N,) int the instance each pose is a candidate for: poses of the same
            instance are alternatives and never hide each other.
        casts: (N,) bool which poses hide others (e.g. one candidate per instance).
        in_front: (N, P) bool contour points seen, updated in place.

    """
    count, points = in_front.shape
    for m in range(count):
        if not casts[m]:
            continue
        u_low, u_high = centres[m, :, 0].min(), centres[m, :, 0].max()
        v_low, v_high = centres[m, :, 1].min(), centres[m, :, 1].max()
        per_band = OUTLINE_BANDS / (v_high - v_low)
        if not (v_high > v_low and math.isfinite(u_low + u_high + v_low + v_high)
                and math.isfinite(per_band)):
            continue        # no area, or not finite: it covers nothing
        starts, edges = _outline_bands(centres[m], v_low, per_band, OUTLINE_BANDS)
        for n in range(count):
            if instances[m] == instances[n] or depths[m] >= depths[n]:
                continue
            for k in range(points):
                u, v = centres[n, k, 0], centres[n, k, 1]
                if in_front[n, k] and u_low <= u <= u_high and v_low <= v <= v_high:
                    band = min(int((v - v_low) * per_band), OUTLINE_BANDS - 1)
                    if _inside_outline(u, v, centres[m], band, starts, edges):
                        in_front[n, k] = False


@numba.njit(**_NUMBA)
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


@numba.njit(**_NUMBA)
def _count_samples(samples, sample_counts, pose, line, counts, totals, sign):
    """Add (sign 1) or remove (-1) one line's colour samples to or from a window's counts."""
    for side in range(2):
        taken = sample_counts[pose, line, side]
        for i in range(taken):
            counts[side, samples[pose, line, side, i]] += sign
        totals[side] += sign * taken


@numba.njit(**_NUMBA)
def _log_ratio(f, g, bound):
    """Return log(f / g) of two colour frequencies, within +-bound; 0 when both are 0."""
    if f == 0.0 and g == 0.0:
        return 0.0
    tiny = np.finfo(np.float64).tiny
    return min(max(math.log(f + tiny) - math.log(g + tiny), -bound), bound)


@numba.njit(**_NUMBA)
def _line_pixel(bins, width, last_pixel, start_u, start_v, step_u, step_v, offset):
    """Return (column, row, colour bin) of the pixel ``offset`` along a line from its start."""
    # A valid line lies on the image (>= -0.5 before the shift, truncation rounds); the
    # guard only keeps a float32 rounding at the last pixel in.
    col = int(start_u + step_u * offset)
    row = int(start_v + step_v * offset)
    return col, row, bins[min(row * width + col, last_pixel)]


@numba.njit(**_NUMBA)
def _sigmoid(log_odds):
    """Return the float32 probability of float32 log-odds (clipped to +-50 first)."""
    log_odds = min(max(log_odds, np.float32(-50.0)), np.float32(50.0))
    return np.float32(1.0) / (np.float32(1.0) + np.exp(-log_odds))


@numba.njit(parallel=True, **_NUMBA)
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


@numba.njit(parallel=True, **_NUMBA)
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


@numba.njit(**_NUMBA)
def gradient_hessian(rotation, translation, points_model, centres, normals, valid, mean,
                     variance, scale, weight_scale, fx, fy, cx, cy):
    """
    Each pose's pull from its lines: (N, 6) gradient, (N, 6, 6) Gauss-Newton Hessian.

    Args:
        rotation: (N, 3, 3) model-to-camera rotations.
        translation: (N, 3) translations, metres.
        points_model: (N, P, 3) contour points, model frame, metres.
        centres: (N, P, 2) projected contour points when the lines were made.
        normals: (N, P, 2) unit outward normals of the lines.
        valid: (N, P) bool lines that count.
        mean: (N, P) the contour distributions' means, segments.
        variance: (N, P) their variances, segments squared.
        scale: pixels per segment.
        weight_scale: a line's weight is weight_scale / variance.
        fx: focal length in u, pixels.
        fy: focal length in v, pixels.
        cx: principal point u, pixels.
        cy: principal point v, pixels.

    Over the increment (rotation vector, translation, both in the model frame), each
    valid line's projected point moves along its normal by J . theta segments; its residual
    is mean - (its offset from the centre, in segments).

    """
    count, lines = points_model.shape[0], points_model.shape[1]
    gradient = np.zeros((count, 6))
    hessian = np.zeros((count, 6, 6))
    jacobian = np.empty(6)
    for n in range(count):
        r = rotation[n]
        for k in range(lines):
            if not valid[n, k]:
                continue
            px, py, pz = points_model[n, k, 0], points_model[n, k, 1], points_model[n, k, 2]
            x = r[0, 0] * px + r[0, 1] * py + r[0, 2] * pz + translation[n, 0]
            y = r[1, 0] * px + r[1, 1] * py + r[1, 2] * pz + translation[n, 1]
            z = r[2, 0] * px + r[2, 1] * py + r[2, 2] * pz + translation[n, 2]
            if abs(z) <= 1e-6:
                z = 1e-6
            fx_z, fy_z = fx / z, fy / z
            n_u, n_v = normals[n, k, 0], normals[n, k, 1]
            delta = (n_u * (x * fx_z + cx - centres[n, k, 0])
                     + n_v * (y * fy_z + cy - centres[n, k, 1])) / scale
            d_x, d_y = n_u * fx_z / scale, n_v * fy_z / scale
            d_z = -(n_u * x * fx_z + n_v * y * fy_z) / z / scale
            # The camera-frame derivative turned into the model frame: d @ R.
            t_x = d_x * r[0, 0] + d_y * r[1, 0] + d_z * r[2, 0]
            t_y = d_x * r[0, 1] + d_y * r[1, 1] + d_z * r[2, 1]
            t_z = d_x * r[0, 2] + d_y * r[1, 2] + d_z * r[2, 2]
            jacobian[0] = py * t_z - pz * t_y
            jacobian[1] = pz * t_x - px * t_z
            jacobian[2] = px * t_y - py * t_x
            jacobian[3], jacobian[4], jacobian[5] = t_x, t_y, t_z
            weight = weight_scale / variance[n, k]
            residual = (mean[n, k] - delta) * weight
            for a in range(6):
                gradient[n, a] += residual * jacobian[a]
                wa = weight * jacobian[a]
                for b in range(a, 6):
                    hessian[n, a, b] += wa * jacobian[b]
        for a in range(6):
            for b in range(a):
                hessian[n, a, b] = hessian[n, b, a]
    return gradient, hessian
