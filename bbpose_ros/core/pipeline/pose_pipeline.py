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
The pose pipeline: image -> detections -> rotations -> translations -> poses.

Each stage is a callable, so learned stages and ground-truth oracles plug in alike:

* a detector ``detect(image_rgb) -> list[Detection]``;
* a rotation estimator ``estimate(image_rgb, camera, detections) -> (N, 3, 3)``
  model-to-camera (egocentric) rotations, one per detection, or several per detection
  (``poses.RotationHypotheses``), which ``hypotheses.HypothesisSelector`` ranks by how
  well each explains the box;
* the Bounding Box Equation for the translations (``bbox_equation``);
* optionally the dense correspondences (``correspondences``): a pose per detection by PnP
  over the predicted surface coordinates, as a further candidate, predicted masks for the
  refiner, and amodal masks that correct the detections' boxes (``box_correction``,
  ``box_source``) before the rotations and the Bounding Box Equation;
* optionally a refiner (``refinement.PoseRefiner``) that aligns each pose, or the few
  best hypotheses of each detection, with the image and keeps the best-scored one.

The values passed between the stages (Detection, PoseEstimate, ...) live in ``poses``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from bbpose_ros.core.geometry.bbox_equation import pad_point_sets, solve_translations
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.pipeline.box_correction import corrected_detections
from bbpose_ros.core.pipeline.hypotheses import HypothesisSelector
from bbpose_ros.core.pipeline.latency import StageTimer
from bbpose_ros.core.pipeline.poses import (Detection, FrameResult, PoseEstimate,
                                            RotationHypotheses)
from bbpose_ros.core.refine.foreground_masks import ForegroundMasks
from bbpose_ros.core.util.errors import InputError

if TYPE_CHECKING:
    from bbpose_ros.core.data.models import ObjectModel
    from bbpose_ros.core.inference.options import PipelineOptions
    from bbpose_ros.core.pipeline.correspondences import (DenseCorrespondenceEstimator,
                                                          DenseMaps)
    from bbpose_ros.core.pipeline.refinement import PoseRefiner


class PosePipeline:
    """
    Runs the stages on one image at a time.

    Args:
        models: {name: ObjectModel} of the objects to report.
        options: the PipelineOptions the stages were built for; the pipeline reads
            ``refine``, ``refine_hypotheses``, ``pose_source``, ``dense_translation``,
            ``dense_mask`` and ``box_source`` from it.
        detector: callable image -> detections, or None when detections are always given.
        rotation_estimator: callable (image, camera, detections) -> (N, 3, 3) rotations or
            RotationHypotheses, or None when rotations are always given.
        hypothesis_selector: the HypothesisSelector that ranks RotationHypotheses; None: one
            of the options (without masks), made when hypotheses first come.
        refiner: a ``refinement.PoseRefiner`` (its ``best_of`` refines candidate poses and
            keeps the best-scored one per detection); given exactly when ``options.refine``.
        correspondences: a ``correspondences.DenseCorrespondenceEstimator``, or None (Q-Net's
            path alone): its masks guide the refiner, and with ``options.uses_dense`` its PnP
            poses are candidates too (placed first: unrefined, a found PnP pose is reported);
            with ``options.corrects_boxes`` its amodal masks correct the boxes.

    Raises:
        InputError: a refiner without ``options.refine``, or ``options.refine`` without one;
            ``options.corrects_boxes`` without correspondences.

    """

    def __init__(self, models: Mapping[str, ObjectModel], options: PipelineOptions,
                 detector: Callable[[np.ndarray], list[Detection]] | None = None,
                 rotation_estimator: Callable[
                     [np.ndarray, CameraIntrinsics, list[Detection]],
                     np.ndarray | RotationHypotheses] | None = None,
                 hypothesis_selector: HypothesisSelector | None = None,
                 refiner: PoseRefiner | None = None,
                 correspondences: DenseCorrespondenceEstimator | None = None) -> None:
        if options.refine != (refiner is not None):
            raise InputError(f'options.refine is {options.refine} but the pipeline was given '
                             f'{"no" if refiner is None else "a"} refiner')
        if options.corrects_boxes and correspondences is None:
            raise InputError(f'options.box_source is {options.box_source} but the pipeline '
                             'was given no dense correspondences')
        self.models = dict(models)
        self.options = options
        self._point_index = {name: i for i, name in enumerate(self.models)}
        self._points = pad_point_sets([m.hull_points for m in self.models.values()])
        self.detector = detector
        self.rotation_estimator = rotation_estimator
        self.hypothesis_selector = hypothesis_selector
        self.refiner = refiner
        self.correspondences = correspondences

    def estimate(self, image_rgb: np.ndarray, camera: CameraIntrinsics,
                 detections: Iterable[Detection] | None = None,
                 rotations: npt.ArrayLike | RotationHypotheses | None = None) -> FrameResult:
        """
        Estimate the poses of the configured objects in one frame.

        Args:
            image_rgb: (H, W, 3) uint8 image, H x W matching ``camera``.
            camera: CameraIntrinsics of the image.
            detections: optional list of Detection to use instead of the detector.
            rotations: optional (N, 3, 3) rotations or RotationHypotheses to use instead of
                the estimator.

        Returns:
            A FrameResult; poses keep the detections' order. With ``box_source``
            'dense_mask' or 'both' a pose's ``detection`` holds the box its translation was
            solved with (the corrected one, or the detector's for the detector's candidate).

        """
        timer = StageTimer()
        if detections is None:
            if self.detector is None:
                raise InputError('the pipeline has no detector and no detections were given')
            detections = self.detector(image_rgb)
            timer.lap('detector')
        detections = [d for d in detections if d.object_name in self.models]
        # The dense net's PnP poses are candidates unless the rotations are given.
        dense_poses = self.options.uses_dense and rotations is None
        dense = None      # (DenseMaps, PnP poses or None when only the masks are used)
        if detections and self.correspondences is not None:
            dense = (self.correspondences(image_rgb, camera, detections) if dense_poses
                     else (self.correspondences.maps(image_rgb, detections), None))
            timer.lap('correspondences')
        # The amodal masks rank Q-Net's hypotheses and judge the refined candidates.
        amodal = None if dense is None else dense_masks(dense[0], 'amodal')
        # Each box solved with (the corrected one first: unrefined, it is reported).
        box_sets = [detections]
        if dense is not None and self.options.corrects_boxes:
            corrected = corrected_detections(detections, dense[0].amodal, dense[0].squares_uv,
                                             self.correspondences.config.crop_size)
            box_sets = [corrected] + ([detections] if self.options.box_source == 'both'
                                      else [])
            timer.lap('box_correction')
        source = 'given' if rotations is not None else 'qnet'
        if detections and rotations is None and self.rotation_estimator is not None:
            # Q-Net sees the detector's crops: the corrected boxes' crops did not improve its
            # rotations (docs/experiments.md).
            rotations = self.rotation_estimator(image_rgb, camera, detections)
            timer.lap('rotation')
        if detections and rotations is None and not (dense is not None and dense_poses):
            raise InputError('the pipeline has no rotation estimator and no rotations were '
                             'given')
        groups = [[] for _ in detections]
        if dense is not None and dense_poses:
            for k, pose in self._dense_candidates(camera, box_sets, dense[1]):
                groups[k].append(pose)
        if rotations is not None and detections:
            count = 1
            if isinstance(rotations, RotationHypotheses):
                if self.hypothesis_selector is None:
                    self.hypothesis_selector = HypothesisSelector(self.models, self.options)
                # Without refinement the best-ranked hypothesis alone is solved.
                rotations = self.hypothesis_selector.ranked(
                    camera, box_sets[0], rotations,
                    self.options.refine_hypotheses if self.options.refine else 1, amodal)
                count = rotations.shape[1]
                timer.lap('hypothesis_selection')
            for boxed in box_sets:
                solved = self.translations(camera, [d for d in boxed for _ in range(count)],
                                           np.reshape(rotations, (-1, 3, 3)), source)
                for k, pose in enumerate(solved):
                    groups[k // count].append(pose)
        timer.lap('translation')
        found = [k for k, group in enumerate(groups) if group]
        if self.refiner is None or not found:
            return FrameResult([groups[k][0] for k in found], timer.total())
        masks = None if dense is None else self.masks_of(dense[0])
        poses = self.refiner.best_of(image_rgb, camera, [groups[k] for k in found],
                                     None if masks is None else masks.take(found),
                                     None if amodal is None else amodal.take(found))
        timer.lap('refinement')
        return FrameResult(poses, timer.total())

    def masks_of(self, maps: DenseMaps) -> ForegroundMasks | None:
        """Return the refiner's masks of a frame's DenseMaps (``dense_mask``), or None."""
        kind = self.options.dense_mask
        return None if kind == 'none' else dense_masks(maps, kind)

    def _dense_candidates(self, camera, box_sets, dense_poses):
        """
        Yield (detection index, PoseEstimate) of the PnP poses, per dense_translation.

        PnP's own translation once, the Bounding Box Equation's with each box set's boxes.
        """
        found = [(k, p) for k, p in enumerate(dense_poses) if p is not None]
        if self.options.dense_translation in ('pnp', 'both'):
            yield from ((k, PoseEstimate(box_sets[0][k], p.rotation, p.translation,
                                         source='pnp')) for k, p in found)
        if self.options.dense_translation in ('bbox_equation', 'both') and found:
            for boxed in box_sets:
                solved = self.translations(camera, [boxed[k] for k, _ in found],
                                           [p.rotation for _, p in found], 'pnp_rotation')
                yield from zip([k for k, _ in found], solved)

    def translations(self, camera: CameraIntrinsics, detections: Sequence[Detection],
                     rotations: npt.ArrayLike, source: str = 'qnet') -> list[PoseEstimate]:
        """Solve the Bounding Box Equation for all detections of a frame in one batch."""
        if not detections:
            return []
        rotations = np.asarray(rotations, dtype=float).reshape(-1, 3, 3)
        if len(rotations) != len(detections):
            raise InputError(f'{len(rotations)} rotations for {len(detections)} detections')
        points = self._points[[self._point_index[d.object_name] for d in detections]]
        boxes = np.stack([d.box_uv for d in detections])
        solution = solve_translations(rotations, boxes, points, camera.fx, camera.fy,
                                      camera.cx, camera.cy)
        return [PoseEstimate(d, r, t, source=source)
                for d, r, t in zip(detections, rotations, solution.translations)]


def dense_masks(maps: DenseMaps, kind: str) -> ForegroundMasks:
    """Return a frame's DenseMaps' 'amodal' or 'visible' masks over their squares."""
    return ForegroundMasks(maps.amodal if kind == 'amodal' else maps.visible, maps.squares_uv)
