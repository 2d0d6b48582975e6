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

from dataclasses import dataclass, field
import math

import numpy as np
import numpy.typing as npt

from bbpose_ros.core.errors import InputError
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.rotations import exp_so3
from bbpose_ros.core.refine.color_histograms import color_bins, ColorHistograms
from bbpose_ros.core.refine.viewpoint_model import ViewpointModel

FUNCTION_LENGTH = 8         # segments of the smoothed step function
DISTRIBUTION_LENGTH = 12    # contour positions considered on each line
FUNCTION_AMPLITUDE = 0.43   # the step function goes from 0.5 + a to 0.5 - a
FUNCTION_SLOPE = 0.5        # its slope, in segments
LINE_SEGMENTS = FUNCTION_LENGTH + DISTRIBUTION_LENGTH - 1
MAX_HISTOGRAM_RUN_PX = 20.0     # pixels on either side of the contour that feed the colours
AGREEMENT_PX = 2.0              # a line agrees when its contour lies this close (scale 1)


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
            background on both sides of its contour point (at scale 1).

    """

    scales: tuple[int, ...] = (6, 4, 2, 1)
    standard_deviations: tuple[float, ...] = (15.0, 5.0, 3.5, 1.5)
    iterations: int = 10
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
        if not (self.tikhonov_rotation >= 0 and self.tikhonov_translation >= 0):
            raise InputError('Tikhonov damping must be >= 0')
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
            end, 0..1: the pose's confidence.
        status: 'ok', or why the pose was left as given ('behind_camera', 'outside_image',
            'too_few_lines').
        histograms: the colour model at the end (a track keeps it for the next frame).

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
    """Correspondence lines of one iteration (N valid lines)."""

    points_model: np.ndarray     # (N, 3)
    centres_uv: np.ndarray       # (N, 2) projected contour points when the lines were made
    normals_uv: np.ndarray       # (N, 2) unit 2D normals, outwards
    mean: np.ndarray             # (N,) contour position along the line, segments
    variance: np.ndarray         # (N,) segments squared
    log_distribution: np.ndarray  # (N, DISTRIBUTION_LENGTH)


def _step_functions():
    x = np.arange(FUNCTION_LENGTH) - (FUNCTION_LENGTH - 1) / 2.0
    h_f = 0.5 - FUNCTION_AMPLITUDE * np.tanh(x / (2.0 * FUNCTION_SLOPE))
    return h_f, 1.0 - h_f


_H_F, _H_B = _step_functions()
_WINDOWS = np.arange(DISTRIBUTION_LENGTH)[:, None] + np.arange(FUNCTION_LENGTH)[None, :]
_MIN_VARIANCE = max(1.0 / (2.0 * math.atanh(2.0 * FUNCTION_AMPLITUDE) ** 2), FUNCTION_SLOPE)
_POSITIONS = np.arange(DISTRIBUTION_LENGTH) - (DISTRIBUTION_LENGTH - 1) / 2.0


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
               iterations: int | None = None, fine_only: bool = False) -> Refinement:
        """
        Refine one pose.

        Args:
            image_rgb: (H, W, 3) uint8 image matching ``camera``.
            camera: CameraIntrinsics of the image.
            rotation: (3, 3) initial model-to-camera rotation.
            translation: (3,) initial translation, metres.
            histograms: colour model to start from (a track's); None: measured around the
                initial pose.
            iterations: correspondence iterations for this call (default: the config's).
            fine_only: take the last ``iterations`` entries of the scale schedule (a track,
                already close) instead of starting from the coarsest.

        Returns:
            A Refinement; a start behind the camera or with too few contour lines inside the
            image comes back unchanged with its status, never as an exception.

        """
        rotation = np.array(rotation, dtype=float).reshape(3, 3)
        translation = np.array(translation, dtype=float).reshape(3)
        if image_rgb.shape[:2] != (camera.height, camera.width):
            raise InputError(f'image {image_rgb.shape[1]}x{image_rgb.shape[0]} does not match '
                             f'the camera {camera.width}x{camera.height}')
        if not (np.all(np.isfinite(rotation)) and np.all(np.isfinite(translation))):
            return Refinement(rotation, translation, 0.0, 'behind_camera', histograms)
        if translation[2] <= 0.5 * self.model.diameter:
            return Refinement(rotation, translation, 0.0, 'behind_camera', histograms)
        config = self.config
        fresh = self._line_colors(image_rgb, camera, rotation, translation)
        if fresh is None:
            return Refinement(rotation, translation, 0.0, 'outside_image', histograms)
        if histograms is None:
            histograms = fresh
        iterations = config.iterations if iterations is None else iterations
        offset = max(len(config.scales) - iterations, 0) if fine_only else 0
        for iteration in range(offset, offset + iterations):
            scale = config.scales[min(iteration, len(config.scales) - 1)]
            sigma = config.standard_deviations[min(iteration,
                                                   len(config.standard_deviations) - 1)]
            lines = self._lines(image_rgb, camera, rotation, translation, histograms, scale)
            if lines is None or len(lines.mean) < 6:
                status = 'outside_image' if lines is None else 'too_few_lines'
                return Refinement(rotation, translation, 0.0, status, histograms)
            for _ in range(config.newton_steps):
                rotation, translation = self._newton_step(camera, rotation, translation, lines,
                                                          scale, sigma)
                if translation[2] <= 0.5 * self.model.diameter:
                    return Refinement(rotation, translation, 0.0, 'behind_camera', histograms)
            if config.histogram_rate > 0.0:
                seen = self._line_colors(image_rgb, camera, rotation, translation)
                if seen is not None:
                    histograms = histograms.blended(seen, config.histogram_rate)
        score = self.score(image_rgb, camera, rotation, translation)
        return Refinement(rotation, translation, score, 'ok', histograms)

    def score(self, image_rgb: np.ndarray, camera: CameraIntrinsics, rotation: np.ndarray,
              translation: np.ndarray) -> float:
        """
        Share of the view's lines whose contour distribution (scale 1) peaks on the pose.

        Colour models fitted to a few thousand pixels would explain almost any silhouette,
        so the score is cross-validated: the lines of even index are judged with colours
        learned on the odd ones and the other way round.
        """
        count = self.model.points.shape[1]
        halves = np.arange(count) % 2 == 0
        agreeing = 0
        for judged in (halves, ~halves):
            histograms = self._line_colors(image_rgb, camera, rotation, translation, ~judged)
            if histograms is None:
                continue
            lines = self._lines(image_rgb, camera, rotation, translation, histograms, 1, judged)
            if lines is None:
                continue
            near = np.abs(_POSITIONS) <= AGREEMENT_PX
            mass = np.exp(lines.log_distribution)[:, near].sum(axis=1)
            agreeing += np.count_nonzero(mass >= 0.5)
        return float(agreeing / count)

    # -- correspondence lines -------------------------------------------------------------

    def _project_view(self, camera, rotation, translation):
        view = self.model.closest_view(rotation, translation)
        points = self.model.points[view]
        points_cam = points @ rotation.T + translation
        z = points_cam[:, 2]
        safe_z = np.where(z > 1e-6, z, 1e-6)
        centres = np.column_stack([camera.fx * points_cam[:, 0] / safe_z + camera.cx,
                                   camera.fy * points_cam[:, 1] / safe_z + camera.cy])
        normals = (self.model.normals[view] @ rotation.T)[:, :2]
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-9)
        px_per_m = camera.fx / safe_z
        foreground_px = self.model.foreground_m[view] * px_per_m
        background_px = self.model.background_m[view] * px_per_m
        return points, centres, normals, foreground_px, background_px, z > 1e-6

    def _line_colors(self, image_rgb, camera, rotation, translation, chosen=None):
        """Histograms of the pixels just inside and just outside the projected contour."""
        points, centres, normals, foreground_px, background_px, in_front = self._project_view(
            camera, rotation, translation)
        if chosen is not None:
            in_front = in_front & chosen
        offsets = np.arange(int(MAX_HISTOGRAM_RUN_PX)) + 0.5
        inside = offsets[None, :] < np.minimum(foreground_px - 1.0, MAX_HISTOGRAM_RUN_PX)[:, None]
        outside = offsets[None, :] < np.minimum(background_px - 1.0,
                                                MAX_HISTOGRAM_RUN_PX)[:, None]
        uv_in = centres[:, None, :] - offsets[None, :, None] * normals[:, None, :]
        uv_out = centres[:, None, :] + offsets[None, :, None] * normals[:, None, :]
        in_front = in_front[:, None]
        f_colors = _gather(image_rgb, uv_in, inside & in_front)
        b_colors = _gather(image_rgb, uv_out, outside & in_front)
        if len(f_colors) < 20 or len(b_colors) < 20:
            return None
        return ColorHistograms.from_colors(f_colors, b_colors)

    def _lines(self, image_rgb, camera, rotation, translation, histograms, scale, chosen=None):
        points, centres, normals, foreground_px, background_px, in_front = self._project_view(
            camera, rotation, translation)
        if chosen is not None:
            in_front = in_front & chosen
        continuous = np.minimum(foreground_px, background_px)
        valid = in_front & (continuous >= self.config.min_continuous_px)
        length = LINE_SEGMENTS * scale
        offsets = np.arange(length) - (length - 1) / 2.0
        uv = centres[:, None, :] + offsets[None, :, None] * normals[:, None, :]
        cols = np.floor(uv[..., 0] + 0.5).astype(np.int64)
        rows = np.floor(uv[..., 1] + 0.5).astype(np.int64)
        on_image = ((cols >= 0) & (cols < camera.width) & (rows >= 0)
                    & (rows < camera.height)).all(axis=1)
        valid &= on_image
        if not valid.any():
            return None
        cols, rows = cols[valid], rows[valid]
        bins = color_bins(image_rgb[rows, cols]).reshape(len(cols), LINE_SEGMENTS, scale)
        table_f, table_b = histograms.log_posteriors()
        log_f = table_f[bins].sum(axis=2)
        log_b = table_b[bins].sum(axis=2)
        top = np.maximum(log_f, log_b)
        seg_f, seg_b = np.exp(log_f - top), np.exp(log_b - top)
        total = seg_f + seg_b
        seg_f, seg_b = seg_f / total, seg_b / total
        terms = seg_f[:, _WINDOWS] * _H_F + seg_b[:, _WINDOWS] * _H_B
        log_distribution = np.log(terms).sum(axis=2)
        log_distribution -= log_distribution.max(axis=1, keepdims=True)
        distribution = np.exp(log_distribution)
        distribution /= distribution.sum(axis=1, keepdims=True)
        mean = distribution @ _POSITIONS
        variance = np.maximum(distribution @ _POSITIONS ** 2 - mean ** 2, _MIN_VARIANCE)
        return _Lines(points[valid], centres[valid], normals[valid], mean, variance,
                      np.log(np.maximum(distribution, 1e-30)))

    # -- optimisation ---------------------------------------------------------------------

    def _newton_step(self, camera, rotation, translation, lines, scale, sigma):
        points_cam = lines.points_model @ rotation.T + translation
        x, y, z = points_cam.T
        fx_z, fy_z = camera.fx / z, camera.fy / z
        u = x * fx_z + camera.cx
        v = y * fy_z + camera.cy
        n_u, n_v = lines.normals_uv.T
        delta = (n_u * (u - lines.centres_uv[:, 0]) + n_v * (v - lines.centres_uv[:, 1])) / scale
        d_centre = np.column_stack([n_u * fx_z, n_v * fy_z,
                                    -(n_u * x * fx_z + n_v * y * fy_z) / z]) / scale
        d_translation = d_centre @ rotation
        jacobian = np.hstack([np.cross(lines.points_model, d_translation), d_translation])
        weight = _MIN_VARIANCE / (sigma / scale) ** 2
        residual_gradient = weight * (lines.mean - delta) / lines.variance
        gradient = jacobian.T @ residual_gradient
        hessian = (jacobian * (weight / lines.variance)[:, None]).T @ jacobian
        damping = np.diag([self.config.tikhonov_rotation] * 3
                          + [self.config.tikhonov_translation] * 3)
        theta = np.linalg.solve(hessian + damping, gradient)
        new_rotation = rotation @ exp_so3(theta[:3])
        new_translation = translation + rotation @ theta[3:]
        return new_rotation, new_translation


def _gather(image_rgb, uv, keep):
    """(K, 3) colours at the kept (..., 2) positions that fall inside the image."""
    height, width = image_rgb.shape[:2]
    cols = np.floor(uv[..., 0] + 0.5).astype(np.int64)
    rows = np.floor(uv[..., 1] + 0.5).astype(np.int64)
    keep = keep & (cols >= 0) & (cols < width) & (rows >= 0) & (rows < height)
    return image_rgb[rows[keep], cols[keep]]
