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
Region-based pose refinement: align the model's silhouette with the image's colours.

The method is SRT3D's (Stoiber et al. 2022, "SRT3D: A Sparse Region-Based 3D Object
Tracking Approach for the Real World"), in numpy and vectorised over lines:

* the viewpoint model's view closest to the current pose gives contour points and normals;
  projected, each defines a *correspondence line* through the contour point along its
  2D normal (pointing out of the object);
* the pixels of a line, grouped in segments of ``scale`` pixels, get a foreground
  probability from the colour histograms; a smoothed step function slid along the line gives
  a discrete distribution of where the contour is on that line; its mean and variance;
* Newton steps on the 6-DoF pose (a rotation vector and a translation, both in the model
  frame: x' = exp(theta_r) x + theta_t) pull each projected contour point towards its
  line's mean, weighted by the inverse variance, with Tikhonov damping;
* the scale shrinks over the iterations (coarse lines see far, fine ones are precise).

Poses are model-to-camera (egocentric): x_cam = rotation @ x_model + translation, metres.
Pixel coordinates are continuous with pixel centres at integers (``CameraIntrinsics``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
import math

import numpy as np
import numpy.typing as npt

from bbpose_ros.core.errors import InputError
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.rotations import exp_so3
from bbpose_ros.core.refine.color_histograms import (BINS_PER_CHANNEL, color_bins,
                                                     ColorHistograms)
from bbpose_ros.core.refine.viewpoint_model import ViewpointModel

FUNCTION_LENGTH = 8         # segments of the smoothed step function
DISTRIBUTION_LENGTH = 12    # contour positions considered on each line
FUNCTION_AMPLITUDE = 0.43   # the step function goes from 0.5 + a to 0.5 - a
FUNCTION_SLOPE = 0.5        # its slope, in segments
LINE_SEGMENTS = FUNCTION_LENGTH + DISTRIBUTION_LENGTH - 1
MAX_HISTOGRAM_RUN_PX = 20.0     # pixels on either side of the contour that feed the colours
HISTOGRAM_STRIDE_PX = 2.0       # of which every second one is sampled
AGREEMENT_PX = 1.5              # a line agrees when its contour lies this close (scale 1)


@dataclass(frozen=True)
class RefinerConfig:
    """
    Settings of the region-based refinement.

    Attributes:
        scales: segment size in pixels, per correspondence iteration (the last repeats).
        standard_deviations: expected contour error in pixels per iteration: it weights the
            lines against the Tikhonov damping (larger: smaller, safer steps).
        iterations: correspondence iterations; each re-projects the lines and computes
            their distributions.
        newton_steps: pose updates per correspondence iteration.
        tikhonov_rotation: damping of the rotation step (per radian squared).
        tikhonov_translation: damping of the translation step (per metre squared).
        histogram_rate: after each correspondence iteration the colour histograms move this
            far towards those seen at the current pose (0: keep the initial ones).
        min_continuous_px: a line needs this many pixels of uninterrupted foreground and
            background on both sides of its contour point (in pixels at every scale).

    """

    scales: tuple[int, ...] = (6, 4, 2, 1)
    standard_deviations: tuple[float, ...] = (15.0, 5.0, 3.5, 1.5)
    iterations: int = 20
    newton_steps: int = 2
    tikhonov_rotation: float = 1000.0
    tikhonov_translation: float = 30000.0
    histogram_rate: float = 1.0
    min_continuous_px: float = 3.0

    def __post_init__(self) -> None:
        if not self.scales or min(self.scales) < 1:
            raise InputError(f'refinement scales must be integers >= 1, got {self.scales}')
        if len(self.standard_deviations) == 0 or not min(self.standard_deviations) > 0:
            raise InputError('refinement standard deviations must be > 0, got '
                             f'{self.standard_deviations}')
        if self.iterations < 1 or self.newton_steps < 1:
            raise InputError('refinement needs at least one iteration and one Newton step')
        if not (self.tikhonov_rotation > 0 and self.tikhonov_translation > 0):
            raise InputError('Tikhonov damping must be > 0 (it keeps every Newton step '
                             'solvable, also for a pose without lines)')
        if not 0.0 <= self.histogram_rate <= 1.0:
            raise InputError(f'histogram_rate must be in [0, 1], got {self.histogram_rate}')


@dataclass(frozen=True)
class Refinement:
    """
    The outcome of one refinement.

    Attributes:
        rotation: (3, 3) refined model-to-camera rotation.
        translation: (3,) refined translation, metres.
        score: share of the view's contour lines that agree with the colour model at the
            end, 0..1: the pose's confidence (0 unless 'ok').
        status: 'ok', or why the pose was given back as it started: 'behind_camera' (not
            finite, or the model origin nearer than half a diameter in depth, at the start or
            during the run), 'outside_image', 'too_few_lines'.
        histograms: the colour model at the end; for a start with a given model (a
            track's), the colours measured at the final pose, to blend into it.

    """

    rotation: np.ndarray
    translation: np.ndarray
    score: float
    status: str
    histograms: ColorHistograms | None = field(default=None, repr=False)

    @property
    def ok(self) -> bool:
        """Tell whether the refinement ran (the pose may still be wrong: see ``score``)."""
        return self.status == 'ok'


@dataclass
class _Lines:
    """Correspondence lines of one iteration for N poses of P lines each."""

    valid: np.ndarray            # (N, P) bool
    points_model: np.ndarray     # (N, P, 3)
    centres_uv: np.ndarray       # (N, P, 2) projected contour points when the lines were made
    normals_uv: np.ndarray       # (N, P, 2) unit 2D normals, outwards
    mean: np.ndarray             # (N, P) contour position along the line, segments
    variance: np.ndarray         # (N, P) segments squared
    distribution: np.ndarray     # (N, P, DISTRIBUTION_LENGTH)


def _step_functions():
    x = np.arange(FUNCTION_LENGTH) - (FUNCTION_LENGTH - 1) / 2.0
    h_f = 0.5 - FUNCTION_AMPLITUDE * np.tanh(x / (2.0 * FUNCTION_SLOPE))
    return h_f, 1.0 - h_f


_H_F, _H_B = _step_functions()
_H_B32, _H_DIFF32 = _H_B.astype(np.float32), (_H_F - _H_B).astype(np.float32)
_WINDOWS = np.arange(DISTRIBUTION_LENGTH)[:, None] + np.arange(FUNCTION_LENGTH)[None, :]
_MIN_VARIANCE = max(1.0 / (2.0 * math.atanh(2.0 * FUNCTION_AMPLITUDE) ** 2), FUNCTION_SLOPE)
_POSITIONS = np.arange(DISTRIBUTION_LENGTH) - (DISTRIBUTION_LENGTH - 1) / 2.0
_NEAR = np.abs(_POSITIONS) <= AGREEMENT_PX
_BINS = BINS_PER_CHANNEL ** 3
_MIN_LINES = 6
_MAX_LOG_RATIO = math.log((1.0 - 1e-4) / 1e-4)


class RegionRefiner:
    """
    Refines poses of one object against an RGB image.

    Args:
        model: the object's ViewpointModel.
        config: RefinerConfig.

    """

    def __init__(self, model: ViewpointModel, config: RefinerConfig | None = None) -> None:
        self.model = model
        self.config = config or RefinerConfig()

    def refine(self, image_rgb: np.ndarray, camera: CameraIntrinsics,
               rotation: npt.ArrayLike, translation: npt.ArrayLike,
               histograms: ColorHistograms | None = None,
               iterations: int | None = None, first_iteration: int = 0) -> Refinement:
        """
        Refine one pose (``refine_poses`` with one pose of this object).

        Args:
            image_rgb: (H, W, 3) uint8 image matching ``camera``.
            camera: CameraIntrinsics of the image.
            rotation: (3, 3) initial model-to-camera rotation.
            translation: (3,) initial translation, metres.
            histograms: colour model to start from (a track's); None: measured around the
                initial pose.
            iterations: correspondence iterations for this call (default: the config's).
            first_iteration: where in the scale schedule to start (a track, already close,
                starts at a fine scale).

        """
        return refine_poses(color_bins(image_rgb), camera, [self.model], [rotation],
                            [translation], self.config, [histograms], iterations,
                            first_iteration)[0]


def refine_poses(bins: np.ndarray, camera: CameraIntrinsics,
                 models: Sequence[ViewpointModel], rotations: Sequence[npt.ArrayLike],
                 translations: Sequence[npt.ArrayLike], config: RefinerConfig,
                 histograms: Sequence[ColorHistograms | None] | None = None,
                 iterations: int | None = None, first_iteration: int = 0
                 ) -> list[Refinement]:
    """
    Refine N poses in one image at once (all arrays carry the pose as first axis).

    Args:
        bins: (H, W) ``color_bins`` of the image; H x W must match ``camera``.
        camera: CameraIntrinsics of the image.
        models: per pose, the ViewpointModel of its object (all with the same number of
            points per view).
        rotations: per pose, the (3, 3) initial model-to-camera rotation.
        translations: per pose, the (3,) initial translation, metres.
        config: RefinerConfig.
        histograms: per pose, a colour model to start from, or None (measured around the
            initial pose).
        iterations: correspondence iterations (default: the config's).
        first_iteration: index of the first iteration in the scale schedule: tracks,
            already close, start at a fine scale; a refinement stopped after k iterations
            continues at k (with ``histogram_rate`` 1 and no given colours, the colour model
            is the one measured at the pose it stopped at, as it would have been).

    Returns:
        Per pose, a Refinement; a start behind the camera or with too few contour lines
        inside the image comes back unchanged with its status, never as an exception.

    """
    count = len(models)
    if first_iteration < 0:
        raise InputError(f'first_iteration must be >= 0, got {first_iteration}')
    if bins.shape[:2] != (camera.height, camera.width):
        raise InputError(f'image {bins.shape[1]}x{bins.shape[0]} does not match the camera '
                         f'{camera.width}x{camera.height}')
    if count == 0:
        return []
    start_rotation = np.array(rotations, dtype=float).reshape(count, 3, 3)
    start_translation = np.array(translations, dtype=float).reshape(count, 3)
    rotation, translation = start_rotation.copy(), start_translation.copy()
    batch = _Batch(models, bins, camera, config.min_continuous_px)
    status = np.full(count, 'ok', dtype=object)
    finite = np.isfinite(rotation).all(axis=(1, 2)) & np.isfinite(translation).all(axis=1)
    rotation[~finite], translation[~finite] = np.eye(3), [0.0, 0.0, 1.0]
    status[~finite | (translation[:, 2] <= 0.5 * batch.diameters)] = 'behind_camera'
    given = list(histograms) if histograms is not None else [None] * count
    # A given colour model (a track's) is kept through the iterations, as SRT3D does within
    # a frame; one measured around the start is re-measured as the pose improves.
    learning = np.array([h is None for h in given])
    fresh_f, fresh_b, seen = batch.line_colors(rotation, translation)
    status[(status == 'ok') & ~seen] = 'outside_image'
    hist_f = np.stack([fresh_f[k] if h is None else h.foreground for k, h in enumerate(given)])
    hist_b = np.stack([fresh_b[k] if h is None else h.background for k, h in enumerate(given)])
    iterations = config.iterations if iterations is None else iterations
    seen_at_end = None      # colours measured at the final poses, when an iteration did it
    for iteration in range(first_iteration, first_iteration + iterations):
        active = status == 'ok'
        if not active.any():
            break
        scale = config.scales[min(iteration, len(config.scales) - 1)]
        sigma = config.standard_deviations[min(iteration, len(config.standard_deviations) - 1)]
        lines = batch.lines(rotation, translation, hist_f, hist_b, scale)
        few = active & (lines.valid.sum(axis=1) < _MIN_LINES)
        status[few] = 'too_few_lines'
        active &= ~few
        for _ in range(config.newton_steps):
            step_r, step_t = _newton_steps(camera, rotation, translation, lines, scale, sigma,
                                           config)
            before = rotation[active]
            rotation[active] = before @ step_r[active]
            translation[active] += (before @ step_t[active][..., None])[..., 0]
            behind = active & (translation[:, 2] <= 0.5 * batch.diameters)
            status[behind] = 'behind_camera'
            active &= ~behind
        if config.histogram_rate > 0.0:
            seen_at_end = seen_f, seen_b, seen = batch.line_colors(rotation, translation)
            update = active & seen & learning
            rate = config.histogram_rate
            hist_f[update] = (1.0 - rate) * hist_f[update] + rate * seen_f[update]
            hist_b[update] = (1.0 - rate) * hist_b[update] + rate * seen_b[update]
    scores = batch.scores(rotation, translation)
    if not learning.all():      # what a track learns from this frame: the colours at the end
        seen_f, seen_b, seen = seen_at_end or batch.line_colors(rotation, translation)
        final = ~learning & seen
        hist_f[final], hist_b[final] = seen_f[final], seen_b[final]
    failed = status != 'ok'
    rotation[failed], translation[failed] = start_rotation[failed], start_translation[failed]
    return [Refinement(rotation[k], translation[k],
                       float(scores[k]) if status[k] == 'ok' else 0.0, str(status[k]),
                       ColorHistograms(hist_f[k], hist_b[k]))
            for k in range(count)]


class _Batch:
    """The viewpoint models and image of one refine_poses call, with the line sampling."""

    def __init__(self, models, bins, camera, min_continuous_px):
        self.min_continuous_px = min_continuous_px
        self.bins = bins.ravel()
        self.camera = camera
        self.diameters = np.array([m.diameter for m in models])
        poses_of = {}
        for k, model in enumerate(models):
            poses_of.setdefault(id(model), (model, []))[1].append(k)
        self.groups = [(model, np.array(poses)) for model, poses in poses_of.values()]
        self.lines_per_view = models[0].points.shape[1]
        self._projected = None
        if any(m.points.shape[1] != self.lines_per_view for m in models):
            raise InputError('viewpoint models refined together need the same points per view')

    def project(self, rotation, translation):
        """
        Lines of each pose's closest view: model points, centres, normals, run lengths.

        The last projection is kept: colours and lines are measured at the same poses.
        """
        key = np.concatenate([rotation.ravel(), translation.ravel()])
        if self._projected is not None and np.array_equal(key, self._projected[0]):
            return self._projected[1]
        points, normals_model, runs_f, runs_b = (
            np.empty((len(rotation), self.lines_per_view) + tail, dtype=np.float32)
            for tail in ((3,), (3,), (), ()))
        for model, poses in self.groups:
            views = model.closest_views(rotation[poses], translation[poses])
            points[poses], normals_model[poses] = model.points[views], model.normals[views]
            runs_f[poses], runs_b[poses] = model.foreground_m[views], model.background_m[views]
        camera = self.camera
        points_cam = points @ rotation.transpose(0, 2, 1) + translation[:, None, :]
        z = points_cam[..., 2]
        in_front = z > 1e-6
        safe_z = np.where(in_front, z, 1e-6)
        centres = np.stack([camera.fx * points_cam[..., 0] / safe_z + camera.cx,
                            camera.fy * points_cam[..., 1] / safe_z + camera.cy], axis=-1)
        normals = normals_model @ rotation[:, :2, :].transpose(0, 2, 1)
        normals /= np.maximum(np.linalg.norm(normals, axis=-1, keepdims=True), 1e-9)
        px_per_m = camera.fx / safe_z
        projected = points, centres, normals, runs_f * px_per_m, runs_b * px_per_m, in_front
        for array in projected:
            array.flags.writeable = False       # shared with the next caller at this pose
        self._projected = key, projected
        return projected

    def line_colors(self, rotation, translation, chosen=None):
        """
        Colour histograms just inside and just outside each pose's projected contour.

        Returns:
            ((N, BINS) foreground, (N, BINS) background, (N,) bool: enough pixels seen).

        """
        _, centres, normals, runs_f, runs_b, in_front = self.project(rotation, translation)
        if chosen is not None:
            in_front = in_front & chosen
        offsets = np.arange(0.5, MAX_HISTOGRAM_RUN_PX, HISTOGRAM_STRIDE_PX)
        counts = []
        for sign, runs in ((-1.0, runs_f), (1.0, runs_b)):
            keep = (offsets < np.minimum(runs - 1.0, MAX_HISTOGRAM_RUN_PX)[..., None]) \
                & in_front[..., None]
            cols, rows = (np.floor(_along_lines(centres[..., axis] + 0.5, normals[..., axis],
                                                sign * offsets)).astype(np.int64)
                          for axis in (0, 1))
            keep &= (cols >= 0) & (cols < self.camera.width) & (rows >= 0) \
                & (rows < self.camera.height)
            pose = np.broadcast_to(np.arange(len(rotation))[:, None, None], keep.shape)
            bins = self.bins[rows[keep] * self.camera.width + cols[keep]]
            counts.append(np.bincount(pose[keep] * _BINS + bins,
                                      minlength=len(rotation) * _BINS
                                      ).reshape(len(rotation), _BINS).astype(float))
        totals = [c.sum(axis=1, keepdims=True) for c in counts]
        enough = (totals[0][:, 0] >= 10) & (totals[1][:, 0] >= 10)
        return (counts[0] / np.maximum(totals[0], 1.0), counts[1] / np.maximum(totals[1], 1.0),
                enough)

    def lines(self, rotation, translation, hist_f, hist_b, scale, chosen=None):
        """Sample the correspondence lines of every pose at ``scale`` (see _Lines)."""
        points, centres, normals, runs_f, runs_b, in_front = self.project(rotation,
                                                                          translation)
        camera = self.camera
        length = LINE_SEGMENTS * scale
        half = (length - 1) / 2.0
        # A line is straight: it lies on the image when both its end pixels do.
        ends = np.stack([centres - half * normals, centres + half * normals])
        on_image = np.all((ends[..., 0] >= -0.5) & (ends[..., 0] < camera.width - 0.5)
                          & (ends[..., 1] >= -0.5) & (ends[..., 1] < camera.height - 0.5),
                          axis=0)
        valid = in_front & (np.minimum(runs_f, runs_b) >= self.min_continuous_px) & on_image
        if chosen is not None:
            valid &= chosen
        # Valid lines have coordinates >= -0.5, so truncating u + 0.5 rounds to the nearest
        # pixel; invalid ones are clipped into the image and ignored.
        cols, rows = (np.clip(_along_lines(centres[..., axis] + 0.5, normals[..., axis],
                                           np.arange(length) - half).astype(np.int32),
                              0, size - 1)
                      for axis, size in enumerate((camera.width, camera.height)))
        line_bins = self.bins[rows * camera.width + cols]
        # log(p_f / (1 - p_f)) with p_f = f / (f + b) clipped to [1e-4, 1 - 1e-4]; 0 for a
        # colour neither histogram has seen. In float64: a track's blended histograms keep
        # bins far below float32's range.
        tiny = np.finfo(float).tiny
        log_ratio_table = np.clip(np.log(hist_f + tiny) - np.log(hist_b + tiny),
                                  -_MAX_LOG_RATIO, _MAX_LOG_RATIO).astype(np.float32).ravel()
        pose = np.arange(len(rotation))[:, None, None] * _BINS
        log_ratio = log_ratio_table[pose + line_bins].reshape(
            *valid.shape, LINE_SEGMENTS, scale).sum(axis=-1)
        seg_f = 1.0 / (1.0 + np.exp(-np.clip(log_ratio, -50.0, 50.0)))
        # h_f * p_f + h_b * (1 - p_f) = h_b + (h_f - h_b) * p_f, in float32 (the biggest array)
        terms = _H_B32 + seg_f[..., _WINDOWS] * _H_DIFF32
        log_distribution = np.log(terms).sum(axis=-1, dtype=np.float64)
        log_distribution -= log_distribution.max(axis=-1, keepdims=True)
        distribution = np.exp(log_distribution)
        distribution /= distribution.sum(axis=-1, keepdims=True)
        mean = distribution @ _POSITIONS
        variance = np.maximum(distribution @ _POSITIONS ** 2 - mean ** 2, _MIN_VARIANCE)
        return _Lines(valid, points, centres, normals, mean, variance, distribution)

    def scores(self, rotation, translation):
        """
        (N,) share of each pose's lines whose contour distribution (scale 1) peaks on it.

        Colour models fitted to a few thousand pixels would explain almost any silhouette,
        so the score is cross-validated: the lines of odd index are judged with colours
        learned on the even ones.
        """
        even = np.arange(self.lines_per_view) % 2 == 0
        hist_f, hist_b, seen = self.line_colors(rotation, translation, even)
        lines = self.lines(rotation, translation, hist_f, hist_b, 1, ~even)
        agreeing = (lines.distribution[..., _NEAR].sum(axis=-1) >= 0.5) & lines.valid
        return np.where(seen, agreeing.sum(axis=1) / np.count_nonzero(~even), 0.0)


def _along_lines(starts, directions, offsets):
    """(N, P, L) float32 coordinates starts + offsets * directions of (N, P) lines."""
    # One image axis at a time: numpy broadcasts over a trailing (u, v) axis of length 2
    # in many short inner loops, much slower.
    return starts.astype(np.float32)[..., None] \
        + directions.astype(np.float32)[..., None] * np.asarray(offsets, dtype=np.float32)


def _newton_steps(camera, rotation, translation, lines, scale, sigma, config):
    """Per pose, the Newton step: (N, 3, 3) rotation increment, (N, 3) model-frame shift."""
    points_cam = lines.points_model @ rotation.transpose(0, 2, 1) + translation[:, None, :]
    x, y, z = np.moveaxis(points_cam, -1, 0)
    z = np.where(np.abs(z) > 1e-6, z, 1e-6)
    fx_z, fy_z = camera.fx / z, camera.fy / z
    u = x * fx_z + camera.cx
    v = y * fy_z + camera.cy
    n_u, n_v = lines.normals_uv[..., 0], lines.normals_uv[..., 1]
    delta = (n_u * (u - lines.centres_uv[..., 0]) + n_v * (v - lines.centres_uv[..., 1])) / scale
    d_centre = np.stack([n_u * fx_z, n_v * fy_z, -(n_u * x * fx_z + n_v * y * fy_z) / z],
                        axis=-1) / scale
    d_translation = d_centre @ rotation
    jacobian = np.concatenate([np.cross(lines.points_model, d_translation), d_translation],
                              axis=-1)
    weight = np.where(lines.valid, _MIN_VARIANCE / (sigma / scale) ** 2 / lines.variance, 0.0)
    weighted = jacobian * weight[..., None]
    gradient = ((lines.mean - delta)[:, None, :] @ weighted)[:, 0]
    hessian = np.matmul(weighted.transpose(0, 2, 1), jacobian)
    hessian += np.diag([config.tikhonov_rotation] * 3 + [config.tikhonov_translation] * 3)
    theta = np.linalg.solve(hessian, gradient[..., None])[..., 0]
    return exp_so3(theta[:, :3]), theta[:, 3:]
