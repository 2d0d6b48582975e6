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
The pipeline's refinement stage: each pose aligned with the image by ``refine.refiner``.

It runs after the Bounding Box Equation, whose translation and the chosen rotation are the
start; the silhouette corrects the depth that a box with a side a few pixels off gets
wrong, as much as the rotation. The refinement score
becomes the pose's confidence; poses scored below ``refine_min_score`` are dropped, which
rejects detections whose silhouette the image does not support.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
import dataclasses
import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.pipeline.mask_agreement import MaskAgreement
from bbpose_ros.core.pipeline.poses import PoseEstimate
from bbpose_ros.core.refine.color_histograms import color_bins, ColorHistograms
from bbpose_ros.core.refine.foreground_masks import ForegroundMasks
from bbpose_ros.core.refine.refiner import (compile_kernels, refine_poses, Refinement,
                                            RefinerConfig)
from bbpose_ros.core.refine.viewpoint_cache import load_viewpoint_models
from bbpose_ros.core.refine.viewpoint_model import ViewpointModel

if TYPE_CHECKING:
    from bbpose_ros.core.data.models import ObjectModel


class PoseRefiner:
    """
    Refine the poses of a frame in one batch (``refine_poses``), each with its object's model.

    Args:
        viewpoint_models: {name: ViewpointModel} of the objects that can be refined; poses
            of other objects pass unchanged.
        options: the PipelineOptions: ``refine_min_score`` and ``refine_mask_choice_weight``
            here, the other ``refine_*`` settings in ``refine_poses``.
        config: the method's RefinerConfig, shared by all objects (default: the shipped);
            its ``screening_iterations`` bound the run of each of a detection's candidates
            before only the best-scored continues.

    Where a detection's candidates come with a predicted amodal mask (``best_of``'s
    ``choice_masks``), each that ran is chosen by its merit, the score +
    ``refine_mask_choice_weight`` x the soft IoU (0..1, ``mask_agreement``) of its
    silhouette with the mask, and, with the config's keep_better_start (which measures the
    score at the start), a refinement that lowers the merit gives its start back with the
    score there (``refine_min_score`` then judges that score): the mask judges the whole
    object where the score judges a band around the contour.

    """

    def __init__(self, viewpoint_models: Mapping[str, ViewpointModel],
                 options: PipelineOptions, config: RefinerConfig = RefinerConfig()) -> None:
        self.options = options
        self.config = config
        self.viewpoint_models = dict(viewpoint_models)
        self._agreement = MaskAgreement(self.viewpoint_models)

    def __call__(self, image_rgb: np.ndarray, camera: CameraIntrinsics,
                 poses: Sequence[PoseEstimate], masks: ForegroundMasks | None = None,
                 choice_masks: ForegroundMasks | None = None) -> list[PoseEstimate]:
        """Refine the poses (with masks, if any: see ``best_of``); keep those scored enough."""
        return self.best_of(image_rgb, camera, [[pose] for pose in poses], masks,
                            choice_masks)

    def best_of(self, image_rgb: np.ndarray, camera: CameraIntrinsics,
                candidates: Sequence[Sequence[PoseEstimate]],
                masks: ForegroundMasks | None = None,
                choice_masks: ForegroundMasks | None = None) -> list[PoseEstimate]:
        """
        Refine the candidate poses of each detection and keep the best one.

        Every candidate gets the config's ``screening_iterations``; the best of each detection
        (by its score, or with ``choice_masks`` by its merit: score +
        ``refine_mask_choice_weight`` x mask agreement) then continues to the end of the
        schedule. With ``choice_masks`` and the config's keep_better_start, a refinement that
        lowered the merit gives its start back.

        Args:
            image_rgb: (H, W, 3) uint8 image.
            camera: its CameraIntrinsics.
            candidates: per detection, its candidate poses (e.g. one per rotation
                hypothesis), all of the same object.
            masks: per detection, a predicted foreground mask (the dense net's), or None:
                the colours alone.
            choice_masks: per detection, the dense net's amodal mask its candidates'
                silhouettes are compared with in choosing one and in keeping the
                refinement, or None: the score alone.

        Returns:
            Per detection, the best refined candidate when it scores >= refine_min_score, in the
            given order; detections of objects without a viewpoint model keep their first
            candidate unrefined.

        """
        jobs = [(k, pose) for k, group in enumerate(candidates) for pose in group
                if pose.object_name in self.viewpoint_models]
        bins = color_bins(image_rgb)
        # Resuming re-measures the colours at the pose reached, which is what a colour model
        # re-measured in full after every iteration holds anyway.
        screening = self.config.screening_iterations
        screened = any(len(group) > 1 for group in candidates) \
            and screening < self.config.iterations \
            and self.config.histogram_rate == 1.0
        results = self._refine(bins, camera, jobs, [(p.rotation, p.translation) for _, p in jobs],
                               masks, screening if screened else None)
        best = {}
        # A failed candidate (score 0, its start given back) gets no agreement: any
        # candidate that ran stays ahead of it, as by the score alone.
        scores = [r.score for r in results]
        merits = np.where([r.ok for r in results],
                          self._merits(camera, [k for k, _ in jobs],
                                       [p.object_name for _, p in jobs],
                                       [(r.rotation, r.translation) for r in results], scores,
                                       choice_masks), scores)
        for (k, pose), result, merit in zip(jobs, results, merits):
            if k not in best or merit > best[k][2]:
                best[k] = (pose, result, merit)
        # {detection: (its chosen candidate, the refinement's end, the score at the start)}
        chosen = {k: (pose, result, result.start_score) for k, (pose, result, _) in best.items()}
        if screened:
            # Winners that failed the screening stay failed, as they would have in one run.
            going = [(k, pose, result) for k, (pose, result, _) in chosen.items() if result.ok]
            finished = self._refine(
                bins, camera, [(k, pose) for k, pose, _ in going],
                [(result.rotation, result.translation) for *_, result in going], masks,
                self.config.iterations - screening, screening,
                prior_centres=[(pose.rotation, pose.translation) for _, pose, _ in going])
            for (k, pose, _), result in zip(going, finished):
                if not result.ok:       # a failure gives the candidate's own start back
                    result = dataclasses.replace(result, rotation=pose.rotation,
                                                 translation=pose.translation)
                chosen[k] = (pose, result, chosen[k][2])
        if choice_masks is not None:
            self._give_back_starts(camera, chosen, choice_masks)
        refined = []
        for k, group in enumerate(candidates):
            if k not in chosen:
                if group[0].object_name not in self.viewpoint_models:
                    refined.append(group[0])
                continue
            pose, result, _ = chosen[k]
            if result.score >= self.options.refine_min_score:
                others = sorted(((merit, r) for (j, p), r, merit in zip(jobs, results, merits)
                                 if j == k and p is not pose and r.ok),
                                key=lambda item: -item[0])
                refined.append(dataclasses.replace(
                    with_refinement(pose, result),
                    alternatives=tuple((r.rotation, r.translation, r.score) for _, r in others)))
        return refined

    def _merits(self, camera, detections, names, poses, scores, choice_masks):
        """(J,) scores + ``refine_mask_choice_weight`` x the poses' agreement with the masks."""
        weight = self.options.refine_mask_choice_weight
        scores = np.asarray(scores, dtype=float)
        if choice_masks is None or weight == 0.0 or not len(detections):
            return scores
        agreement = self._agreement(camera, names, [r for r, _ in poses], [t for _, t in poses],
                                    choice_masks.take(detections))
        return scores + weight * agreement

    def _give_back_starts(self, camera, chosen, choice_masks):
        """
        Give a detection its start back where the refinement lowered its merit (in place).

        ``RefinerConfig.keep_better_start`` judges by the score alone; with a mask, the
        merit (``_merits``) judges the start against the end, so that a right start the
        contour evidence pulls off (its fixed point) is kept where the mask disagrees.
        """
        ran = [(k, pose, result, start) for k, (pose, result, start) in chosen.items()
               if result.ok and math.isfinite(start)]
        if self.options.refine_mask_choice_weight == 0.0 or not ran:
            return
        detections = [k for k, *_ in ran] * 2
        names = [pose.object_name for _, pose, *_ in ran] * 2
        poses = ([(pose.rotation, pose.translation) for _, pose, *_ in ran]
                 + [(result.rotation, result.translation) for *_, result, _ in ran])
        scores = [start for *_, start in ran] + [result.score for *_, result, _ in ran]
        merits = self._merits(camera, detections, names, poses, scores,
                              choice_masks).reshape(2, -1)
        for (k, pose, result, start), back in zip(ran, merits[0] > merits[1]):
            if back:
                chosen[k] = (pose, dataclasses.replace(result, rotation=pose.rotation,
                                                       translation=pose.translation,
                                                       score=start), start)

    def _refine(self, bins, camera, jobs, starts, masks, iterations=None, first_iteration=0,
                prior_centres=None):
        centres = None if prior_centres is None else ([r for r, _ in prior_centres],
                                                      [t for _, t in prior_centres])
        detections = [k for k, _ in jobs]
        # Of a detection's candidates the first (best-ranked) hides the other detections.
        first = [n == 0 or detections[n - 1] != k for n, k in enumerate(detections)]
        return refine_poses(bins, camera, [self.viewpoint_models[p.object_name] for _, p in jobs],
                            [r for r, _ in starts], [t for _, t in starts], self.options,
                            self.config, iterations=iterations, first_iteration=first_iteration,
                            masks=None if masks is None else masks.take(detections),
                            prior_centres=centres, instances=detections, occluders=first)

    def refine_tracks(self, image_rgb: np.ndarray, camera: CameraIntrinsics,
                      names: Sequence[str], rotations: Sequence[np.ndarray],
                      translations: Sequence[np.ndarray],
                      histograms: Sequence[ColorHistograms | None],
                      iterations: int) -> list[Refinement]:
        """Refine tracked poses in one batch (each its own instance), from the fine end."""
        return refine_poses(color_bins(image_rgb), camera,
                            [self.viewpoint_models[name] for name in names], rotations,
                            translations, self.options, self.config, histograms, iterations,
                            max(len(self.config.scales) - iterations, 0),
                            instances=range(len(names)))


def with_refinement(pose: PoseEstimate, result: Refinement) -> PoseEstimate:
    """Move a pose to a refinement's result and score it (unchanged when it did not run)."""
    return dataclasses.replace(pose, rotation=result.rotation, translation=result.translation,
                               refinement_score=result.score)


def load_pose_refiner(models: Mapping[str, ObjectModel], options: PipelineOptions,
                      cache_dir: Path | str | None = None, progress: bool = True,
                      log: Callable[[str], None] | None = None) -> PoseRefiner:
    """
    Build the PoseRefiner of ``options`` for the objects, viewpoint models from the cache.

    The viewpoint models are built where new (once per mesh). The refinement's kernels are
    compiled (or loaded from numba's cache) first, so that the first frame runs at speed.
    """
    compile_kernels()
    return PoseRefiner(load_viewpoint_models(models, cache_dir, progress=progress, log=log),
                       options)
