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
Region-based pose refinement: the loop that aligns the model's silhouette with the image.

The method is SRT3D's (Stoiber et al. 2022, "SRT3D: A Sparse Region-Based 3D Object
Tracking Approach for the Real World"), in numpy and vectorised over lines and poses, in
ICG's separation of concerns:

* ``viewpoint_model``: the object's contour points and normals from many views (cached);
* ``region_modality``: correspondence lines across the projected contour, their colour
  statistics (``color_histograms``) and the pull they give the pose;
* ``optimizer``: damped Newton steps on the 6-DoF pose;
* here, ``refine_poses``: the iterations, the scale schedule (coarse lines see far, fine
  ones are precise), the colour model's updates, the status of each pose and its score.

Poses are model-to-camera (egocentric): x_cam = rotation @ x_model + translation, metres.
Pixel coordinates are continuous with pixel centres at integers (``CameraIntrinsics``).

What a user sets (the ``refine_*`` settings: start prior, threads, occlusions, local
colours) ``refine_poses`` reads from the PipelineOptions under those names; ``RefinerConfig``
holds the method's own constants (scale schedule, damping, colour updates).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
import math

import numpy as np
import numpy.typing as npt

from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.refine import kernel_launch
from bbpose_ros.core.refine.color_histograms import ColorHistograms
from bbpose_ros.core.refine.foreground_masks import ForegroundMasks
from bbpose_ros.core.refine.optimizer import newton_update, start_prior
from bbpose_ros.core.refine.region_modality import RegionModality
from bbpose_ros.core.refine.viewpoint_model import ViewpointModel
from bbpose_ros.core.util.declarations import above_zero, check_settings, setting
from bbpose_ros.core.util.errors import InputError

# A pose with fewer valid correspondence lines in an iteration stops: 'too_few_lines'.
LOCAL_COLORS_MAX_SCALE = 2  # local colour models serve the finer scales (pixels a segment)
MIN_LINES = 6


@dataclass(frozen=True)
class RefinerConfig:
    """
    The method's constants of the region-based refinement, declared as settings are.

    What a user sets are the PipelineOptions' ``refine_*`` settings (``refine_poses``);
    these constants are the method's, set by tests and experiments. Each field's
    description is in its declaration.

    Screening (``screening_iterations``) needs ``histogram_rate`` 1 (colours re-measured in
    full), under which it gives the same pose as refining the chosen candidate in one run,
    unless a start was given back (``keep_better_start``, or the mask merit) or no colours
    can be measured at the pose it reached (then it ends as 'outside_image'); with another
    rate every candidate is refined to the end. The shipped 6 is the whole scale schedule
    once (6, 4, 2, 1) and two more at the finest scale, by which a wrong start shows.

    Raises:
        InputError: 'name: reason' for the first value it does not take.

    """

    scales: tuple[int, ...] = setting(
        (6, 4, 2, 1), 'Segment size in pixels per correspondence iteration (the last '
        'repeats).', low=1, metavar='PX,...')
    standard_deviations: tuple[float, ...] = setting(
        (15.0, 5.0, 3.5, 1.5), 'Expected contour error in pixels per iteration (the last '
        'repeats): it weights the lines against the damping (larger: smaller, safer steps).',
        metavar='PX,...', check=above_zero)
    iterations: int = setting(
        20, 'Correspondence iterations; each re-projects the lines and measures their '
        'distributions.', low=1)
    newton_steps: int = setting(2, 'Pose updates per correspondence iteration.', low=1)
    tikhonov_rotation: float = setting(
        1000.0, 'Damping of the rotation step, per radian squared (> 0: it keeps every '
        'Newton step solvable, also for a pose without lines).', check=above_zero)
    tikhonov_translation: float = setting(
        30000.0, 'Damping of the translation step, per metre squared (> 0, as the '
        "rotation's).", check=above_zero)
    histogram_rate: float = setting(
        1.0, 'How far the colour histograms move after each correspondence iteration '
        'towards those seen at the current pose (0: keep the initial ones).',
        low=0.0, high=1.0)
    min_continuous_px: float = setting(
        3.0, 'Pixels of uninterrupted foreground and background a line needs on both sides '
        'of its contour point (at every scale).', low=0.0)
    mask_weight: float = setting(
        1.0, 'For a pose refined with a predicted foreground mask, how much the mask counts '
        'against the colours (1: the mask alone; see region_modality).', low=0.0, high=1.0)
    keep_better_start: bool = setting(
        True, 'Give back the start of a pose whose score the refinement lowered (the score '
        'is measured at the start too, one pass more).')
    screening_iterations: int = setting(
        6, 'Of a detection with several candidates, each is refined this many iterations '
        'and only the best-scored continues (at least iterations: every candidate is '
        'refined to the end).', low=1)

    def __post_init__(self) -> None:
        check_settings(self)


def prior_information(options: PipelineOptions) -> tuple[float, float]:
    """
    (per radian squared, per metre squared) 1 / variance of the start prior; 0: none.

    The prior (``refine_prior_deg``, ``refine_prior_mm``) is a Gaussian around the start:
    directions the contour hardly constrains (an out-of-plane turn of a round object, the
    depth) then stay near the start instead of drifting with the lines' noise, and a far
    start moves less.
    """
    rotation_rad = math.radians(options.refine_prior_deg)
    translation_m = options.refine_prior_mm / 1000.0
    return (1.0 / rotation_rad ** 2 if rotation_rad else 0.0,
            1.0 / translation_m ** 2 if translation_m else 0.0)


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
        start_score: the score at the start (measured for ``keep_better_start``), NaN when
            it was not measured, 0 unless 'ok'.

    """

    rotation: np.ndarray
    translation: np.ndarray
    score: float
    status: str
    histograms: ColorHistograms | None = field(default=None, repr=False)
    start_score: float = math.nan

    @property
    def ok(self) -> bool:
        """Tell whether the refinement ran (the pose may still be wrong: see ``score``)."""
        return self.status == 'ok'


def refine_poses(bins: np.ndarray, camera: CameraIntrinsics,
                 models: Sequence[ViewpointModel], rotations: Sequence[npt.ArrayLike],
                 translations: Sequence[npt.ArrayLike], options: PipelineOptions,
                 config: RefinerConfig = RefinerConfig(),
                 histograms: Sequence[ColorHistograms | None] | None = None,
                 iterations: int | None = None, first_iteration: int = 0,
                 masks: ForegroundMasks | None = None,
                 prior_centres: tuple[Sequence[npt.ArrayLike], Sequence[npt.ArrayLike]]
                 | None = None, instances: Sequence[int] | None = None,
                 occluders: Sequence[bool] | None = None) -> list[Refinement]:
    """
    Refine N poses in one image at once (all arrays carry the pose as first axis).

    Args:
        bins: (H, W) ``color_bins`` of the image; H x W must match ``camera``.
        camera: CameraIntrinsics of the image.
        models: per pose, the ViewpointModel of its object (all with the same number of
            points per view).
        rotations: per pose, the (3, 3) initial model-to-camera rotation.
        translations: per pose, the (3,) initial translation, metres.
        options: the PipelineOptions, whose ``refine_*`` settings apply: the start prior,
            the threads of the per-line loops (split by pose), the poses' occlusions, the
            local colour models.
        config: the method's RefinerConfig.
        histograms: per pose, a colour model to start from, or None (measured around the
            initial pose).
        iterations: correspondence iterations (default: the config's).
        first_iteration: index of the first iteration in the scale schedule: tracks,
            already close, start at a fine scale; a refinement stopped after k iterations
            continues at k (with ``histogram_rate`` 1 and no given colours, the colour model
            is the one measured at the pose it stopped at, as it would have been).
        masks: per pose, a predicted foreground mask (``foreground_masks``), or None: the
            colours alone.
        prior_centres: (rotations, translations) around which the start prior
            (``refine_prior_deg``, ``refine_prior_mm``) lies, per pose
            (default: the starts); a refinement continued at ``first_iteration`` passes the
            first run's starts, so that it ends where one run would.
        instances: per pose, the object instance (e.g. the detection) it is a candidate
            for. With ``refine_occlusions``, a pose's silhouette hides the
            contour points of other instances' poses farther from the camera; candidates of
            one instance never hide each other. None: no pose hides another (e.g. several
            starts of one object).
        occluders: with ``instances``, per pose, whether its silhouette hides others
            (default: all), e.g. the first candidate of each instance only.

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
    kernel_launch.use_threads(options.refine_threads)
    start_rotation = np.array(rotations, dtype=float).reshape(count, 3, 3)
    start_translation = np.array(translations, dtype=float).reshape(count, 3)
    rotation, translation = start_rotation.copy(), start_translation.copy()
    occlusions = None
    if options.refine_occlusions and instances is not None:
        occlusions = (np.asarray(instances, dtype=np.int64).reshape(count),
                      np.ones(count, bool) if occluders is None
                      else np.asarray(occluders, dtype=bool).reshape(count))
    # Local colour models serve the scales up to LOCAL_COLORS_MAX_SCALE pixels a segment: at
    # the coarse scales the start is far, and a local model learned at a wrong contour
    # confirms it. A start with given colours (a track's) keeps its one model.
    modality = RegionModality(models, bins, camera, config.min_continuous_px, masks,
                              config.mask_weight, occlusions, options)
    status = np.full(count, 'ok', dtype=object)
    finite = np.isfinite(rotation).all(axis=(1, 2)) & np.isfinite(translation).all(axis=1)
    rotation[~finite], translation[~finite] = np.eye(3), [0.0, 0.0, 1.0]
    status[~finite | (translation[:, 2] <= 0.5 * modality.diameters)] = 'behind_camera'
    if prior_centres is None:
        anchor_rotation, anchor_translation = rotation.copy(), translation.copy()
    else:
        anchor_rotation = np.array(prior_centres[0], dtype=float).reshape(count, 3, 3)
        anchor_translation = np.array(prior_centres[1], dtype=float).reshape(count, 3)
        anchor_rotation[~finite], anchor_translation[~finite] = np.eye(3), [0.0, 0.0, 1.0]
    given = list(histograms) if histograms is not None else [None] * count
    # A given colour model (a track's) is kept through the iterations, as SRT3D does within
    # a frame; one measured around the start is re-measured as the pose improves.
    learning = np.array([h is None for h in given])
    fresh_f, fresh_b, seen, local = modality.local_colors(rotation, translation)
    if local is not None:
        local.counts[~learning] = 0     # a given colour model stays the pose's only one
    status[(status == 'ok') & ~seen] = 'outside_image'
    hist_f = np.stack([fresh_f[k] if h is None else h.foreground for k, h in enumerate(given)])
    hist_b = np.stack([fresh_b[k] if h is None else h.background for k, h in enumerate(given)])
    iterations = config.iterations if iterations is None else iterations
    start_scores = modality.scores(rotation, translation) if config.keep_better_start else None
    prior = prior_information(options)
    seen_at_end = None      # colours measured at the final poses, when an iteration did it
    for iteration in range(first_iteration, first_iteration + iterations):
        active = status == 'ok'
        if not active.any():
            break
        scale = config.scales[min(iteration, len(config.scales) - 1)]
        sigma = config.standard_deviations[min(iteration, len(config.standard_deviations) - 1)]
        lines = modality.lines(rotation, translation, hist_f, hist_b, scale,
                               local=local if scale <= LOCAL_COLORS_MAX_SCALE else None)
        few = active & (lines.valid.sum(axis=1) < MIN_LINES)
        status[few] = 'too_few_lines'
        active &= ~few
        for _ in range(config.newton_steps):
            gradient, hessian = modality.gradient_hessian(rotation, translation, lines, scale,
                                                          sigma)
            if any(prior):
                gradient, hessian = start_prior(gradient, hessian, rotation, translation,
                                                anchor_rotation, anchor_translation, *prior)
            newton_update(rotation, translation, gradient, hessian, config.tikhonov_rotation,
                          config.tikhonov_translation, active)
            behind = active & (translation[:, 2] <= 0.5 * modality.diameters)
            status[behind] = 'behind_camera'
            active &= ~behind
        if config.histogram_rate > 0.0:
            seen_f, seen_b, seen, now_local = modality.local_colors(rotation, translation)
            seen_at_end = seen_f, seen_b, seen
            update = (active & seen & learning)[:, None]
            rate = config.histogram_rate
            for model, now in ((hist_f, seen_f), (hist_b, seen_b)):
                np.copyto(model, now if rate == 1.0 else (1.0 - rate) * model + rate * now,
                          where=update)
            if local is not None:       # the lines' samples: the latest ones
                local.samples[update[:, 0]] = now_local.samples[update[:, 0]]
                local.counts[update[:, 0]] = now_local.counts[update[:, 0]]
    scores = modality.scores(rotation, translation)
    if start_scores is not None:        # a refinement that lowers the score is not taken
        back = (status == 'ok') & (start_scores > scores)
        rotation[back], translation[back] = start_rotation[back], start_translation[back]
        scores = np.where(back, start_scores, scores)
    if not learning.all():      # what a track learns from this frame: the colours at the end
        seen_f, seen_b, seen = seen_at_end or modality.line_colors(rotation, translation)
        final = ~learning & seen
        hist_f[final], hist_b[final] = seen_f[final], seen_b[final]
    failed = status != 'ok'
    rotation[failed], translation[failed] = start_rotation[failed], start_translation[failed]
    ok = status == 'ok'
    return [Refinement(rotation[k], translation[k], float(scores[k]) if ok[k] else 0.0,
                       str(status[k]), ColorHistograms(hist_f[k], hist_b[k]),
                       math.nan if start_scores is None else
                       float(start_scores[k]) if ok[k] else 0.0)
            for k in range(count)]


def compile_kernels() -> None:
    """
    Compile the refinement's numba kernels (see ``kernel_launch``) now, not in the first frame.

    numba compiles them once per machine and source (tens of seconds) into its cache and
    loads them from there after that (a fraction of a second); a refinement of a synthetic
    square on a synthetic image does either, for the argument types a real one passes.
    """
    lines = 32
    side = np.linspace(-0.05, 0.05, lines, dtype=np.float32)
    points = np.stack([np.full(lines, 0.05, np.float32), side, np.zeros(lines, np.float32)], 1)
    model = ViewpointModel(np.array([[0.0, 0.0, -1.0]]), points[None],
                           np.tile(np.float32([1.0, 0.0, 0.0]), (1, lines, 1)),
                           np.full((1, lines), 0.1, np.float32),
                           np.full((1, lines), 0.1, np.float32), 0.15)
    camera = CameraIntrinsics(500.0, 500.0, 63.5, 63.5, 128, 128)
    bins = np.zeros((128, 128), np.uint16)
    bins[:, 64:] = 1
    # Two poses, the nearer one hiding part of the other: the occlusion kernel compiles too.
    refine_poses(bins, camera, [model, model], [np.eye(3), np.eye(3)],
                 [[-0.05, 0.0, 1.0], [-0.03, 0.0, 1.2]], PipelineOptions(),
                 RefinerConfig(iterations=1), instances=[0, 1])
