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
The dense correspondence stage: a frame's detections -> dense maps -> PnP poses.

All crops of a frame go through the dense net (``nets.dense``) in one batch; each crop is
cut as Q-Net's (square, the net's ``context``, around the detection's amodal box), and
its maps give a pose by PnP with RANSAC (``geometry.dense_pnp``). The crops' PnP solves run
on a small thread pool (``DenseStageSettings.pnp_threads``): OpenCV releases the GIL, and
each solve seeds its own RANSAC, so the poses do not depend on the pool.
"""

from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
import os

import numpy as np
import torch

from bbpose_ros.core.data.models import ObjectModel
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.dense_grid import model_box
from bbpose_ros.core.geometry.dense_pnp import DensePose, pose_from_dense_maps
from bbpose_ros.core.inference.backends import make_runner
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.nets.crops import extract_crops, FILL_VALUE, square_boxes
from bbpose_ros.core.nets.dense import DenseNet
from bbpose_ros.core.pipeline.poses import Detection
from bbpose_ros.core.util.declarations import check_settings, setting
from bbpose_ros.core.util.errors import InputError


@dataclass(frozen=True)
class DenseStageSettings:
    """
    The dense stage's own settings, below the node's parameters (the defaults serve it).

    Each field's description is in its declaration (``util.declarations``).

    Raises:
        InputError: 'name: reason' for the first value it does not take.

    """

    pnp_threads: int = setting(
        0, "Threads the crops' PnP solves are spread over; 0: one per core, 1: in the "
        'calling thread.', low=0, high=256)

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass(frozen=True)
class DenseMaps:
    """
    The dense net's output for a frame's detections (N crops, M x M maps).

    Attributes:
        coordinates: (N, M, M, 3) normalised model coordinates (``geometry.dense_grid``).
        visible: (N, M, M) visible-mask probability.
        amodal: (N, M, M) amodal-mask probability.
        squares_uv: (N, 4) the crops' squares, full-frame continuous pixels.

    """

    coordinates: np.ndarray
    visible: np.ndarray
    amodal: np.ndarray
    squares_uv: np.ndarray


class DenseCorrespondenceEstimator:
    """
    ``(image_rgb, camera, detections) -> (DenseMaps, [DensePose | None])``.

    Args:
        network: a DenseNet (a copy is prepared for inference by ``make_runner``).
        models: {name: ObjectModel} of the objects it is run on (for the model boxes): the
            network's or some of them.
        options: the PipelineOptions: what runs the network (``backends.make_runner``).
        settings: the stage's own DenseStageSettings (``pnp_threads``).

    Attributes:
        precision: 'fp32': the dense net always runs in float (its int8 graph cost accuracy:
            one uint8 scale cannot cover both coordinates and mask logits).

    """

    precision = 'fp32'

    def __init__(self, network: DenseNet, models: Mapping[str, ObjectModel],
                 options: PipelineOptions,
                 settings: DenseStageSettings = DenseStageSettings()) -> None:
        self.config = network.config
        missing = [name for name in models if name not in self.config.objects]
        if missing:
            raise InputError(f'the dense net has no output for {", ".join(missing)} (it has '
                             f'{", ".join(self.config.objects)})')
        self.index = {name: k for k, name in enumerate(self.config.objects)}
        self.boxes = {name: model_box(model.vertices) for name, model in models.items()}
        self.network = make_runner(network, self._blank_batch(1), options, dynamic_batch=True)
        workers = settings.pnp_threads or os.cpu_count() or 1
        self._pnp_pool = ThreadPoolExecutor(workers, 'dense-pnp') if workers > 1 else None

    def maps(self, image_rgb: np.ndarray, detections: Sequence[Detection]) -> DenseMaps:
        """Compute the dense maps of each detection's crop (one batch)."""
        size = self.config.map_size
        if not detections:
            return DenseMaps(np.zeros((0, size, size, 3)), np.zeros((0, size, size)),
                             np.zeros((0, size, size)), np.zeros((0, 4)))
        squares = square_boxes(np.array([d.box_uv for d in detections], dtype=float),
                               self.config.context)
        crops = extract_crops(image_rgb, squares, self.config.crop_size)
        index = np.array([self.index[d.object_name] for d in detections], dtype=np.int64)
        maps = self.network(crops, index).float()
        return DenseMaps(maps[:, :3].permute(0, 2, 3, 1).numpy(),
                         torch.sigmoid(maps[:, 3]).numpy(), torch.sigmoid(maps[:, 4]).numpy(),
                         squares)

    def __call__(self, image_rgb: np.ndarray, camera: CameraIntrinsics,
                 detections: Sequence[Detection]) -> tuple[DenseMaps, list[DensePose | None]]:
        """Return the maps and one PnP pose per detection (None: too few masked cells)."""
        maps = self.maps(image_rgb, detections)

        def solve(k: int) -> DensePose | None:
            return pose_from_dense_maps(maps.coordinates[k], maps.visible[k],
                                        maps.squares_uv[k], camera,
                                        *self.boxes[detections[k].object_name])
        crops = range(len(detections))
        if self._pnp_pool is None or len(detections) < 2:
            return maps, [solve(k) for k in crops]
        return maps, list(self._pnp_pool.map(solve, crops))

    def _blank_batch(self, count):
        size = self.config.crop_size
        crops = np.full((count, size, size, 3), FILL_VALUE, dtype=np.uint8)
        return crops, np.zeros(count, dtype=np.int64)

    def warm_up(self, max_batch: int) -> None:
        """Run every batch size 1..max_batch once on blank crops (as Q-Net's stage does)."""
        for count in range(1, max_batch + 1):
            self.network(*self._blank_batch(count))
