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
The region modality (SRT3D): correspondence lines across the projected contour.

* The viewpoint model's view closest to the current pose gives contour points and normals;
  projected, each defines a *correspondence line* through the contour point along its
  2D normal (pointing out of the object);
* the pixels of a line, grouped in segments of ``scale`` pixels, get a foreground
  probability from the colour histograms; a smoothed step function slid along the line gives
  a discrete distribution of where the contour is on that line: its mean and variance; a
  predicted silhouette mask (``foreground_masks``) may stand in for or mix with the colours;
* ``RegionModality.gradient_hessian`` turns them into the pull on the 6-DoF pose that
  ``optimizer.newton_step`` solves for.

Poses are model-to-camera (egocentric): x_cam = rotation @ x_model + translation, metres.
Pixel coordinates are continuous with pixel centres at integers (``CameraIntrinsics``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math

import numpy as np

from bbpose_ros.core.errors import InputError
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.refine.color_histograms import BINS_PER_CHANNEL
from bbpose_ros.core.refine.foreground_masks import ForegroundMasks
from bbpose_ros.core.refine.viewpoint_model import ViewpointModel

FUNCTION_LENGTH = 8         # segments of the smoothed step function
DISTRIBUTION_LENGTH = 12    # contour positions considered on each line
FUNCTION_AMPLITUDE = 0.43   # the step function goes from 0.5 + a to 0.5 - a
FUNCTION_SLOPE = 0.5        # its slope, in segments
LINE_SEGMENTS = FUNCTION_LENGTH + DISTRIBUTION_LENGTH - 1
MAX_HISTOGRAM_RUN_PX = 20.0     # pixels on either side of the contour that feed the colours
HISTOGRAM_STRIDE_PX = 2.0       # of which every second one is sampled
AGREEMENT_PX = 1.5              # a line agrees when its contour lies this close (scale 1)


@dataclass
class CorrespondenceLines:
    """The correspondence lines of one iteration, for N poses of P lines each."""

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
MIN_VARIANCE = max(1.0 / (2.0 * math.atanh(2.0 * FUNCTION_AMPLITUDE) ** 2), FUNCTION_SLOPE)
_POSITIONS = np.arange(DISTRIBUTION_LENGTH) - (DISTRIBUTION_LENGTH - 1) / 2.0
_NEAR = np.abs(_POSITIONS) <= AGREEMENT_PX
_BINS = BINS_PER_CHANNEL ** 3
_MAX_LOG_RATIO = math.log((1.0 - 1e-4) / 1e-4)


class RegionModality:
    """
    The region modality of N poses in one image: correspondence lines, colours, gradients.

    Args:
        models: per pose, the ViewpointModel of its object (all with the same number of
            points per view).
        bins: (H, W) ``color_bins`` of the image.
        camera: CameraIntrinsics of the image.
        min_continuous_px: a line needs this many pixels of uninterrupted foreground and
            background on both sides of its contour point.
        masks: per pose, a predicted foreground mask (``foreground_masks``), or None.
        mask_weight: where a pose has a mask, a pixel's foreground log-odds are
            (1 - w) * the colours' + w * the mask's (1: the mask alone).

    """

    def __init__(self, models: Sequence[ViewpointModel], bins: np.ndarray,
                 camera: CameraIntrinsics, min_continuous_px: float,
                 masks: ForegroundMasks | None = None, mask_weight: float = 1.0) -> None:
        self.min_continuous_px = min_continuous_px
        self.masks = masks
        self.mask_weight = float(mask_weight)
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
        """Sample the correspondence lines of every pose at ``scale`` (see CorrespondenceLines)."""
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
        pixel_log_ratio = log_ratio_table[pose + line_bins]
        if self.masks is not None:
            weight = np.float32(self.mask_weight)
            pixel_log_ratio = (1.0 - weight) * pixel_log_ratio \
                + weight * self.masks.log_odds(cols, rows)
        log_ratio = pixel_log_ratio.reshape(*valid.shape, LINE_SEGMENTS, scale).sum(axis=-1)
        seg_f = 1.0 / (1.0 + np.exp(-np.clip(log_ratio, -50.0, 50.0)))
        # h_f * p_f + h_b * (1 - p_f) = h_b + (h_f - h_b) * p_f, in float32 (the biggest array)
        terms = _H_B32 + seg_f[..., _WINDOWS] * _H_DIFF32
        log_distribution = np.log(terms).sum(axis=-1, dtype=np.float64)
        log_distribution -= log_distribution.max(axis=-1, keepdims=True)
        distribution = np.exp(log_distribution)
        distribution /= distribution.sum(axis=-1, keepdims=True)
        mean = distribution @ _POSITIONS
        variance = np.maximum(distribution @ _POSITIONS ** 2 - mean ** 2, MIN_VARIANCE)
        return CorrespondenceLines(valid, points, centres, normals, mean, variance, distribution)

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

    def gradient_hessian(self, rotation: np.ndarray, translation: np.ndarray,
                         lines: CorrespondenceLines, scale: int,
                         sigma: float) -> tuple[np.ndarray, np.ndarray]:
        """
        Return the lines' pull on each pose: (N, 6) gradient, (N, 6, 6) Gauss-Newton Hessian.

        Over the pose increment (a rotation vector, then a translation, both in the model
        frame: x' = exp(theta_r) x + theta_t), each line's projected contour point is pulled
        towards its line's mean, weighted by the inverse variance (scaled by ``sigma``, the
        expected contour error in pixels). ``optimizer.newton_step`` adds the damping.
        """
        camera = self.camera
        points_cam = lines.points_model @ rotation.transpose(0, 2, 1) + translation[:, None, :]
        x, y, z = np.moveaxis(points_cam, -1, 0)
        z = np.where(np.abs(z) > 1e-6, z, 1e-6)
        fx_z, fy_z = camera.fx / z, camera.fy / z
        u = x * fx_z + camera.cx
        v = y * fy_z + camera.cy
        n_u, n_v = lines.normals_uv[..., 0], lines.normals_uv[..., 1]
        delta = (n_u * (u - lines.centres_uv[..., 0])
                 + n_v * (v - lines.centres_uv[..., 1])) / scale
        d_centre = np.stack([n_u * fx_z, n_v * fy_z, -(n_u * x * fx_z + n_v * y * fy_z) / z],
                            axis=-1) / scale
        d_translation = d_centre @ rotation
        jacobian = np.concatenate([np.cross(lines.points_model, d_translation),
                                   d_translation], axis=-1)
        weight = np.where(lines.valid, MIN_VARIANCE / (sigma / scale) ** 2 / lines.variance,
                          0.0)
        weighted = jacobian * weight[..., None]
        gradient = ((lines.mean - delta)[:, None, :] @ weighted)[:, 0]
        hessian = np.matmul(weighted.transpose(0, 2, 1), jacobian)
        return gradient, hessian


def _along_lines(starts, directions, offsets):
    """(N, P, L) float32 coordinates starts + offsets * directions of (N, P) lines."""
    # One image axis at a time: numpy broadcasts over a trailing (u, v) axis of length 2
    # in many short inner loops, much slower.
    return starts.astype(np.float32)[..., None] \
        + directions.astype(np.float32)[..., None] * np.asarray(offsets, dtype=np.float32)
