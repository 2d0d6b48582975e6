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
* the colour model is one pair of histograms per pose, or local (``refine_local_colors``;
  RBOT's localized "tclc" histograms, Tjaden et al. 2018): each line's colours are those
  sampled on the lines near it along the contour, with the pose's histograms as a prior of
  ``LOCAL_PRIOR_PIXELS`` pixels. One pair of histograms gathers its background from all
  around the object, dark shadows and clutter included; where the object is darker than the
  background beside it, its own colours then look ambiguous while the bright background is
  confidently background, and the contour's distribution leans inwards (the silhouette fits
  small, the pose drifts away from the camera). A local model sees the colours beside
  each line only;
* ``RegionModality.gradient_hessian`` turns them into the pull on the 6-DoF pose that
  ``optimizer.newton_update`` solves for.

Poses are model-to-camera (egocentric): x_cam = rotation @ x_model + translation, metres.
Pixel coordinates are continuous with pixel centres at integers (``CameraIntrinsics``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math

import numpy as np

from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.refine import (contour_projection, kernel_launch, line_distributions,
                                    line_gradient, line_histograms)
from bbpose_ros.core.refine.color_histograms import BINS_PER_CHANNEL
from bbpose_ros.core.refine.foreground_masks import ForegroundMasks, OUTSIDE_LOG_ODDS
from bbpose_ros.core.refine.viewpoint_model import ViewpointModel
from bbpose_ros.core.util.errors import InputError

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
MIN_VARIANCE = max(1.0 / (2.0 * math.atanh(2.0 * FUNCTION_AMPLITUDE) ** 2), FUNCTION_SLOPE)
_POSITIONS = np.arange(DISTRIBUTION_LENGTH) - (DISTRIBUTION_LENGTH - 1) / 2.0
_NEAR = np.abs(_POSITIONS) <= AGREEMENT_PX
_BINS = BINS_PER_CHANNEL ** 3
_MAX_LOG_RATIO = math.log((1.0 - 1e-4) / 1e-4)
_HISTOGRAM_OFFSETS = np.arange(0.5, MAX_HISTOGRAM_RUN_PX, HISTOGRAM_STRIDE_PX,
                               dtype=np.float32)
_NO_MASKS, _NO_SQUARES = np.zeros((0, 1, 1), dtype=np.float32), np.zeros((0, 4))
_NO_SAMPLES = np.zeros((0, 1, 2, len(_HISTOGRAM_OFFSETS)), dtype=np.uint16)
_NO_COUNTS = np.zeros((0, 1, 2), dtype=np.int32)
LOCAL_CHUNK_LINES = 2           # lines that share one local colour window
LOCAL_PRIOR_PIXELS = 64.0       # the global colours count as this many pixels of a window


@dataclass
class LocalColors:
    """
    What local colour models are made of: each line's own colour samples (RBOT's tclc).

    Attributes:
        samples: (N, P, 2, S) uint16 colour bins sampled inside (0) and outside (1) each
            line's contour, S per side at most.
        counts: (N, P, 2) int32 how many are set; all 0 for a pose that keeps its global
            colour model (e.g. a track's).

    """

    samples: np.ndarray
    counts: np.ndarray


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
        occlusions: (instances, casts): per pose, the (N,) int instance it is a candidate
            for and the (N,) bool whether its silhouette hides the contours of other
            instances' poses behind it (``contour_projection.hide_occluded``; ICG's model
            occlusions, with the silhouettes of the poses themselves); None: no pose hides
            another.
        options: the PipelineOptions, whose ``refine_local_colors`` > 0 gives local colour
            models (``LocalColors``) of the lines up to this many places before and after
            each line along the contour; 0: one per pose.

    """

    def __init__(self, models: Sequence[ViewpointModel], bins: np.ndarray,
                 camera: CameraIntrinsics, min_continuous_px: float,
                 masks: ForegroundMasks | None = None, mask_weight: float = 1.0,
                 occlusions: tuple[np.ndarray, np.ndarray] | None = None,
                 options: PipelineOptions = PipelineOptions()) -> None:
        self.occlusions = occlusions
        self.refine_local_colors = options.refine_local_colors
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
        count, lines = len(rotation), self.lines_per_view
        points = np.empty((count, lines, 3), dtype=np.float32)
        centres, normals = np.empty((count, lines, 2)), np.empty((count, lines, 2))
        runs_f, runs_b = np.empty((count, lines)), np.empty((count, lines))
        in_front = np.empty((count, lines), dtype=bool)
        camera = self.camera
        for model, poses in self.groups:
            contour_projection.project_contours(
                model.view_directions, model.points, model.normals, model.foreground_m,
                model.background_m, poses, rotation, translation, camera.fx, camera.fy,
                camera.cx, camera.cy, points, centres, normals, runs_f, runs_b, in_front)
        if self.occlusions is not None and count > 1:
            contour_projection.hide_occluded(centres, translation[:, 2].astype(float),
                                             *self.occlusions, in_front)
        projected = points, centres, normals, runs_f, runs_b, in_front
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
        return self.local_colors(rotation, translation, chosen)[:3]

    def local_colors(self, rotation, translation, chosen=None):
        """
        ``line_colors`` and, with ``refine_local_colors``, the lines' own samples.

        Returns:
            (as ``line_colors``, then LocalColors, or None without ``refine_local_colors``).

        """
        _, centres, normals, runs_f, runs_b, in_front = self.project(rotation, translation)
        if chosen is not None:
            in_front = in_front & chosen
        count = len(centres) if self.refine_local_colors > 0 else 0
        local = LocalColors(
            np.zeros((count, self.lines_per_view, 2, len(_HISTOGRAM_OFFSETS)), np.uint16),
            np.zeros((count, self.lines_per_view, 2), np.int32))
        with kernel_launch.parallel_launch():
            hist_f, hist_b, totals = line_histograms.line_color_histograms(
                self.bins, self.camera.width, self.camera.height, centres, normals, runs_f,
                runs_b, in_front, _HISTOGRAM_OFFSETS, MAX_HISTOGRAM_RUN_PX, _BINS,
                local.samples, local.counts)
        return hist_f, hist_b, (totals >= 10).all(axis=1), local if count else None

    def lines(self, rotation, translation, hist_f, hist_b, scale, chosen=None, local=None):
        """
        Sample the correspondence lines of every pose at ``scale`` (see CorrespondenceLines).

        ``local``: LocalColors (with ``refine_local_colors``), or None: ``hist_f``, ``hist_b``
        alone.
        """
        points, centres, normals, runs_f, runs_b, in_front = self.project(rotation,
                                                                          translation)
        camera = self.camera
        half = (LINE_SEGMENTS * scale - 1) / 2.0
        # A line is straight: it lies on the image when both its end pixels do.
        ends = np.stack([centres - half * normals, centres + half * normals])
        on_image = np.all((ends[..., 0] >= -0.5) & (ends[..., 0] < camera.width - 0.5)
                          & (ends[..., 1] >= -0.5) & (ends[..., 1] < camera.height - 0.5),
                          axis=0)
        valid = in_front & (np.minimum(runs_f, runs_b) >= self.min_continuous_px) & on_image
        if chosen is not None:
            valid &= chosen
        masks = self.masks
        with kernel_launch.parallel_launch():
            mean, variance, distribution = line_distributions.contour_distributions(
                self.bins, camera.width, camera.height, centres, normals, valid,
                np.asarray(hist_f, dtype=np.float64), np.asarray(hist_b, dtype=np.float64), scale,
                LINE_SEGMENTS, _H_B32, _H_DIFF32, _POSITIONS, MIN_VARIANCE, _MAX_LOG_RATIO,
                _NO_MASKS if masks is None else masks.log_odds_grid,
                _NO_SQUARES if masks is None else masks.squares_uv.astype(np.float64),
                np.float32(self.mask_weight), np.float32(OUTSIDE_LOG_ODDS),
                _NO_SAMPLES if local is None else local.samples,
                _NO_COUNTS if local is None else local.counts, self.refine_local_colors,
                LOCAL_CHUNK_LINES, LOCAL_PRIOR_PIXELS)
        return CorrespondenceLines(valid, points, centres, normals, mean, variance, distribution)

    def scores(self, rotation, translation):
        """
        (N,) share of each pose's lines whose contour distribution (scale 1) peaks on it.

        Colour models fitted to a few thousand pixels would explain almost any silhouette,
        so the score is cross-validated: the lines of odd index are judged with colours
        learned on the even ones. It is judged with one colour model per pose also where the
        lines are fitted with local ones: a local model learned at a wrong contour would
        vouch for it, and the score stays the same measure whatever the refiner fitted with.
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
        expected contour error in pixels). ``optimizer.newton_update`` adds the damping.
        """
        camera = self.camera
        return line_gradient.gradient_hessian(
            rotation, translation, lines.points_model, lines.centres_uv, lines.normals_uv,
            lines.valid, lines.mean, lines.variance, scale,
            MIN_VARIANCE / (sigma / scale) ** 2, camera.fx, camera.fy, camera.cx, camera.cy)
