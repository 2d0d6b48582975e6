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
How well a pose's silhouette agrees with a predicted mask: a score for rotation hypotheses.

The dense net predicts each detection's amodal mask on an M x M grid over its crop
(``refine.foreground_masks``). A rotation hypothesis, with the translation the Bounding Box
Equation gives it, projects to a silhouette; the right hypothesis covers the predicted mask,
a wrong one (turned the other way, seen from too high) leaves part of it empty and spills
over elsewhere. The score is the soft intersection over union

    sum_cells min(s, p) / sum_cells max(s, p),

s the silhouette's 0/1 cell and p the mask's probability, 0..1. The silhouette is drawn
without rendering: the refiner's viewpoint model stores, for the view closest to the pose,
the silhouette contour in order around the object (``refine.viewpoint_model``), so its
projection filled as one polygon at the mask's grid is the silhouette at that resolution (a
few tens of microseconds a pose). Where the silhouette has several outer parts the contour
joins them, which fills a sliver between them: a small error beside a cell's size.
"""

from collections.abc import Mapping, Sequence

import cv2
import numpy as np
import numpy.typing as npt

from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.refine.foreground_masks import ForegroundMasks
from bbpose_ros.core.refine.viewpoint_model import ViewpointModel
from bbpose_ros.core.util.errors import InputError

_SUBPIXEL_BITS = 4
# Contour points used of a view's (ordered) ones: a mask cell spans several of them.
CONTOUR_STEP = 2


class MaskAgreement:
    """
    Score poses by the soft IoU of their silhouette with predicted masks.

    ``agreement(camera, names, rotations, translations, masks) -> (K,) float`` in 0..1.

    Args:
        viewpoint_models: {name: ViewpointModel} (the refiner's), one per object scored.

    """

    def __init__(self, viewpoint_models: Mapping[str, ViewpointModel]) -> None:
        self.viewpoint_models = dict(viewpoint_models)

    def __call__(self, camera: CameraIntrinsics, names: Sequence[str],
                 rotations: npt.ArrayLike, translations: npt.ArrayLike,
                 masks: ForegroundMasks) -> np.ndarray:
        """
        Score K poses against their masks.

        Args:
            camera: intrinsics of the full frame.
            names: (K,) object name of each pose.
            rotations: (K, 3, 3) model-to-camera rotations.
            translations: (K, 3) metres.
            masks: K masks (``probabilities`` (K, M, M), ``squares_uv`` (K, 4)).

        Returns:
            (K,) soft IoU; 0 for a pose with the object behind the camera.

        Raises:
            InputError: an object without a viewpoint model, or counts that differ.

        """
        rotations = np.asarray(rotations, dtype=float).reshape(-1, 3, 3)
        translations = np.asarray(translations, dtype=float).reshape(-1, 3)
        count = len(names)
        if not len(rotations) == len(translations) == len(masks.probabilities) == count:
            raise InputError(f'{count} names, {len(rotations)} rotations, '
                             f'{len(translations)} translations and '
                             f'{len(masks.probabilities)} masks to score')
        missing = sorted(set(names) - set(self.viewpoint_models))
        if missing:
            raise InputError(f'no viewpoint model for {", ".join(missing)}')
        size = masks.probabilities.shape[-1]
        silhouettes = np.zeros((count, size, size), np.float32)
        for name in dict.fromkeys(names):
            chosen = np.flatnonzero(np.asarray(names) == name)
            silhouettes[chosen] = self.silhouettes(camera, name, rotations[chosen],
                                                   translations[chosen],
                                                   masks.squares_uv[chosen], size)
        union = np.maximum(silhouettes, masks.probabilities).sum(axis=(1, 2))
        overlap = np.minimum(silhouettes, masks.probabilities).sum(axis=(1, 2))
        return np.where(union > 0, overlap / np.maximum(union, 1e-12), 0.0)

    def silhouettes(self, camera: CameraIntrinsics, name: str, rotations: np.ndarray,
                    translations: np.ndarray, squares_uv: npt.ArrayLike,
                    size: int) -> np.ndarray:
        """
        (K, size, size) float32 0/1 silhouettes of K poses of one object over squares' grids.

        Cell (row j, column i) covers the j-th row and i-th column of its square's ``size``
        x ``size`` cells (``geometry.dense_grid``); a cell is 1 when its centre lies inside
        the projected contour. A pose with a contour point not in front of the camera gets
        an empty silhouette.
        """
        model = self.viewpoint_models[name]
        views = model.closest_views(rotations, translations)
        # (K, P, 3) contour points of each pose's view, in the camera frame; every
        # CONTOUR_STEP-th is enough at a mask's resolution.
        contour = model.points[views, ::CONTOUR_STEP]
        points = np.einsum('kij,kpj->kpi', rotations.astype(np.float32), contour) + \
            translations[:, None, :].astype(np.float32)
        squares_uv = np.asarray(squares_uv, dtype=float).reshape(-1, 4)
        cell = (squares_uv[:, 2] - squares_uv[:, 0]) / size
        in_front = np.all(points[..., 2] > 0.0, axis=1)
        uv = camera.project(np.where(in_front[:, None, None], points, 1.0))
        # Cell centres fall on integers: column i's centre is u0 + (i + 0.5) * cell.
        grid = (uv - squares_uv[:, None, :2]) / cell[:, None, None] - 0.5
        # Clipped far outside the grid (cells there stay empty) to keep a point just in
        # front of the camera within int32 at the subpixel scale.
        polygons = np.round(np.clip(grid, -4 * size, 5 * size) *
                            (1 << _SUBPIXEL_BITS)).astype(np.int32)
        canvas = np.zeros((len(points), size, size), np.uint8)
        for k in np.flatnonzero(in_front):
            cv2.fillPoly(canvas[k], [polygons[k]], 1, cv2.LINE_8, _SUBPIXEL_BITS)
        return canvas.astype(np.float32)
