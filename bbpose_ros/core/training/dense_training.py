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
Dense net training on a crop cache with dense targets (format version 2).

Each step draws ``batch`` crops (visible fraction >= ``min_visib``), resizes them to the
network's input, applies photometric augmentation (``augment_batch``) and fits the maps:
L1 on the normalised coordinates over the cells the target covers (visible share >= 0.5),
and binary cross-entropy on the visible and amodal masks (soft targets: each cell's
covered share), summed with ``coordinate_weight`` on the L1.

Symmetric objects get unambiguous targets: of the poses a symmetry makes equivalent
(``models_info.json``'s ``symmetries_discrete``), the one whose allocentric rotation is
closest to the identity (the largest trace of R_allo S), as GDR-Net and EPOS choose, and
the coordinates seen under that pose, ``S^-1 x``. The allocentric rotation (relative to the
ray through the amodal box centre) is what a crop shows, so crops that look alike get
the same target. Validation uses the last ``val_fraction`` of each cache folder.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np
import torch
import torch.nn.functional as F

from bbpose_ros.core.eval.metrics import cm_deg_errors
from bbpose_ros.core.geometry.boxes import box_centres
from bbpose_ros.core.geometry.dense_grid import model_box
from bbpose_ros.core.geometry.dense_pnp import pose_from_dense_maps
from bbpose_ros.core.geometry.rotations import egocentric_to_allocentric
from bbpose_ros.core.nets.crops import square_boxes
from bbpose_ros.core.nets.dense import DenseConfig, DenseNet
from bbpose_ros.core.nets.images import images_to_input
from bbpose_ros.core.training.augment import augment_batch
from bbpose_ros.core.training.crop_cache import instance_split
from bbpose_ros.core.training.device import TrainingDevice
from bbpose_ros.core.training.settings import DenseTrainSettings
from bbpose_ros.core.util.errors import InputError

if TYPE_CHECKING:
    from bbpose_ros.core.data.models import ObjectModel
    from bbpose_ros.core.training.crop_cache import CropCache

# Cells whose visible share reaches this carry a coordinate target.
COORDINATE_CELL_SHARE = 0.5


def target_cells(cache_size: int, map_size: int) -> np.ndarray | None:
    """
    (map_size,) cache cell under each map cell's centre, or None where the sizes agree.

    A cache rendered at another grid size serves a network by nearest-cell resampling of
    its targets (coordinates, visible and amodal shares alike, so a cell's coordinate target
    and its share stay the pair the renderer wrote).
    """
    if cache_size == map_size:
        return None
    return ((np.arange(map_size) + 0.5) * cache_size / map_size).astype(int)


def freeze_early_blocks(network: DenseNet, blocks: int) -> None:
    """
    Keep the trunk's stem and first ``blocks`` blocks at their (ImageNet) weights.

    Blocks 0-4 run at strides 2 to 8: their backward pass is most of a training step's cost
    on the CPU, and the decoder still learns from their features through its laterals.
    """
    trunk = network.trunk
    for module in (trunk._conv_stem, trunk._bn0, *trunk._blocks[:blocks]):
        for parameter in module.parameters():
            parameter.requires_grad_(False)


def canonical_symmetry(rotations_allo: np.ndarray, symmetry_rotations: np.ndarray) -> np.ndarray:
    """
    (n,) index k of the symmetry whose R_allo S_k is closest to the identity.

    ``rotations_allo`` (n, 3, 3), ``symmetry_rotations`` (n, K, 3, 3) (identity first; pad
    with identities). Closest in the rotation angle, i.e. the largest trace; ties go to the
    lower index.
    """
    traces = np.einsum('nij,nkji->nk', rotations_allo, symmetry_rotations)
    return np.argmax(traces > traces.max(axis=1, keepdims=True) - 1e-9, axis=1)


def symmetric_coordinates(coordinates: np.ndarray, transform: np.ndarray, box_min: np.ndarray,
                          box_size: np.ndarray) -> np.ndarray:
    """
    Normalised coordinates (..., 3) seen under the pose P S instead of P: S^-1 x.

    ``transform`` is the (4, 4) symmetry S (metres), box_min / box_size the model box.
    """
    points = box_min + coordinates * box_size
    moved = (points - transform[:3, 3]) @ transform[:3, :3]
    return (moved - box_min) / box_size


class DenseBatches:
    """
    Draws dense training batches from a CropCache with dense targets.

    Args:
        cache: CropCache with dense targets (``dense_size`` > 0; resampled to the
            network's map size M where it differs: ``target_cells``).
        config: DenseConfig of the network.
        models: {name: ObjectModel} for the model boxes and symmetries.
        settings: DenseTrainSettings.
        seed: seed of the draws.
        require_all: refuse a cache that lacks one of the network's objects (False: those
            objects get no batches, as when only a new object's rows learn).

    """

    def __init__(self, cache: CropCache, config: DenseConfig,
                 models: Mapping[str, ObjectModel], settings: DenseTrainSettings,
                 seed: int, require_all: bool = True) -> None:
        if not cache.dense_size:
            raise InputError('the crop cache has no dense targets; render one with "bbpose '
                             f'train render-crops --dense-size {config.map_size}"')
        missing = [name for name in config.objects if name not in cache.objects]
        if missing and require_all:
            raise InputError(f'the crop cache lacks the object(s) {", ".join(missing)}')
        self.cache, self.config, self.settings = cache, config, settings
        self.net_index, self.train_ids, self.val_ids = instance_split(cache, config.objects,
                                                                      settings)
        object_models = [models[name] for name in config.objects]
        self.boxes = np.array([model_box(m.vertices) for m in object_models])  # (O, 2, 3)
        self.symmetries = [m.symmetry_transforms for m in object_models]
        self.symmetry_index = self._canonical_symmetries()
        self.target_cells = target_cells(cache.dense_size, config.map_size)
        self.rng = np.random.default_rng(seed)
        self.generator = torch.Generator().manual_seed(seed)

    def _canonical_symmetries(self):
        """(m,) per cached crop, the symmetry of its target (0: the identity)."""
        cache = self.cache
        index = np.zeros(len(cache.visib), dtype=int)
        for k, transforms in enumerate(self.symmetries):
            ids = np.flatnonzero(self.net_index == k)
            if len(transforms) == 1 or not len(ids):
                continue
            allo = egocentric_to_allocentric(cache.rotation[ids].astype(float),
                                             cache.camera.rays(box_centres(cache.box_uv[ids])))
            index[ids] = canonical_symmetry(
                allo, np.broadcast_to(transforms[:, :3, :3], (len(ids), *transforms[:, :3, :3]
                                                              .shape)))
        return index

    def train_batch(self) -> tuple[torch.Tensor, ...]:
        """Draw a training batch (see ``make``)."""
        ids = self.rng.choice(self.train_ids, self.settings.batch)
        return self.make(ids, self.settings.augment_strength)

    def targets(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return (n, M, M, 3) canonical coordinates, (n, M, M) visible and amodal shares."""
        cache = self.cache
        coordinates = cache.coordinates[ids].astype(np.float32)
        for row, crop in enumerate(ids):
            k = self.symmetry_index[crop]
            if k:
                obj = self.net_index[crop]
                coordinates[row] = symmetric_coordinates(
                    coordinates[row], self.symmetries[obj][k], *self.boxes[obj])
        visible = cache.visible_mask[ids].astype(np.float32) / 255.0
        amodal = cache.amodal_mask[ids].astype(np.float32) / 255.0
        cells = self.target_cells
        if cells is None:
            return coordinates, visible, amodal
        return tuple(maps[:, cells][:, :, cells] for maps in (coordinates, visible, amodal))

    def make(self, ids: np.ndarray, strength: float) -> tuple[torch.Tensor, ...]:
        """
        Build the batch of crops ``ids``, augmented at ``strength`` (0: not at all).

        Returns images (B, 3, S, S), object index (B,), coordinates (B, 3, M, M), visible
        and amodal shares (B, M, M).
        """
        config = self.config
        crops, _ = self.cache.input_crops(ids, None, None, config.crop_size, config.context)
        images = images_to_input(torch.from_numpy(crops))
        images = augment_batch(images, self.generator, strength, self.settings.augment)
        coordinates, visible, amodal = self.targets(ids)
        return (images.contiguous(memory_format=torch.channels_last),
                torch.from_numpy(self.net_index[ids]),
                torch.from_numpy(coordinates).permute(0, 3, 1, 2).contiguous(),
                torch.from_numpy(visible), torch.from_numpy(amodal))


def dense_loss(maps: torch.Tensor, coordinates: torch.Tensor, visible: torch.Tensor,
               amodal: torch.Tensor, coordinate_weight: float = 1.0
               ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """
    Per-crop loss (B,) and its parts {'coordinates', 'visible', 'amodal'} (each (B,)).

    ``maps`` (B, 5, M, M) network output; ``coordinates`` (B, 3, M, M) targets; ``visible``
    and ``amodal`` (B, M, M) cell shares in 0..1. The L1 is the mean over the target's cells
    and the 3 axes (0 for a crop without any), the BCEs the mean over all cells.
    """
    maps = maps.float()
    cells = (visible >= COORDINATE_CELL_SHARE).float()
    l1 = (maps[:, :3] - coordinates).abs().sum(dim=1)
    coordinate_term = (l1 * cells).sum(dim=(1, 2)) / (3 * cells.sum(dim=(1, 2)).clamp(min=1))
    visible_term = F.binary_cross_entropy_with_logits(maps[:, 3], visible,
                                                      reduction='none').mean(dim=(1, 2))
    amodal_term = F.binary_cross_entropy_with_logits(maps[:, 4], amodal,
                                                     reduction='none').mean(dim=(1, 2))
    parts = {'coordinates': coordinate_term, 'visible': visible_term, 'amodal': amodal_term}
    return coordinate_weight * coordinate_term + visible_term + amodal_term, parts


def dense_step(network: DenseNet, optimizer: torch.optim.Optimizer, batches: DenseBatches,
               device: TrainingDevice) -> float:
    """One optimisation step on ``device``; returns the batch's mean loss."""
    images, index, coordinates, visible, amodal = device.put(*batches.train_batch())
    maps = device.forward(network, images, index)
    loss, _ = dense_loss(maps, coordinates, visible, amodal,
                         batches.settings.coordinate_weight)
    return device.minimise(optimizer, loss.mean())


def mask_iou(probability: np.ndarray, share: np.ndarray) -> np.ndarray:
    """(n,) IoU of predicted (probability > 0.5) and true (share >= 0.5) (n, M, M) masks."""
    predicted, true = probability > 0.5, share >= 0.5
    union = (predicted | true).sum(axis=(1, 2))
    return (predicted & true).sum(axis=(1, 2)) / np.maximum(union, 1)


def maps_to_numpy(maps: torch.Tensor) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(n, M, M, 3) coordinates, (n, M, M) visible and amodal probabilities of net maps."""
    maps = maps.float().cpu()
    return (maps[:, :3].permute(0, 2, 3, 1).numpy(), torch.sigmoid(maps[:, 3]).numpy(),
            torch.sigmoid(maps[:, 4]).numpy())


def dense_validation(network: DenseNet, batches: DenseBatches, device: TrainingDevice,
                     count: int = 256, seed: int = 12345) -> dict[str, float]:
    """
    Score held-out crops.

    Loss and parts, median coordinate error (mm, on the target's cells), mask IoUs, and
    the PnP pose (``pose_from_dense_maps``): median rotation error (deg, symmetry-aware)
    and translation error (mm).
    """
    rng = np.random.default_rng(seed)
    ids = np.sort(rng.choice(batches.val_ids, min(count, len(batches.val_ids)),
                             replace=False))
    network.eval()
    with torch.inference_mode():
        images, index, coordinates, visible, amodal = device.put(*batches.make(ids, 0.0))
        maps = network(images, index)
        loss, parts = dense_loss(maps, coordinates, visible, amodal,
                                 batches.settings.coordinate_weight)
    predicted, visible_p, amodal_p = maps_to_numpy(maps)
    true_coordinates, true_visible, true_amodal = batches.targets(ids)
    cache, objects = batches.cache, batches.net_index[ids]
    sizes = batches.boxes[objects, 1]
    error_mm = np.linalg.norm((predicted - true_coordinates) * sizes[:, None, None], axis=-1)
    cells = true_visible >= COORDINATE_CELL_SHARE
    squares = square_boxes(cache.input_box_uv[ids], batches.config.context)
    rotation_errors, translation_errors = [], []
    for row, crop in enumerate(ids):
        box_min, box_size = batches.boxes[objects[row]]
        pose = pose_from_dense_maps(predicted[row], visible_p[row], squares[row],
                                    cache.camera, box_min, box_size)
        if pose is None:
            rotation_errors.append(180.0)
            translation_errors.append(np.inf)
            continue
        re_deg, te_m = cm_deg_errors(pose.rotation, pose.translation,
                                     cache.rotation[crop].astype(float),
                                     cache.translation[crop].astype(float),
                                     batches.symmetries[objects[row]])
        rotation_errors.append(re_deg)
        translation_errors.append(1000 * te_m)
    return {'val_loss': float(loss.mean()),
            'val_coordinates_l1': float(parts['coordinates'].mean()),
            'val_coordinates_mm': float(np.median(1000 * error_mm[cells])),
            'val_visible_iou': float(mask_iou(visible_p, true_visible).mean()),
            'val_amodal_iou': float(mask_iou(amodal_p, true_amodal).mean()),
            'val_pnp_re_deg': float(np.median(rotation_errors)),
            'val_pnp_te_mm': float(np.median(translation_errors))}
