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
Q-Net training on a rendered cache: jittered crops, symmetric-aware Dot Product Loss.

Each step draws ``batch`` instances (visible fraction >= ``min_visib``), jitters their amodal
boxes as a detector would (``box_sigma``: per-side error / box size, the ``side_sigma`` a
detector's validation reports), cuts the square crop the estimator would cut, applies
photometric augmentation and regresses the ground-truth quaternion (wxyz, q0 >= 0),
egocentric or allocentric.
Validation uses the last ``val_fraction`` of the scenes, never seen in training.

``max_inplane_deg`` (not the paper's) trains only on instances whose roll about the optical axis
(``placement.viewpoint_angles``: relative to the model's z axis pointing up in the crop) is
within that many degrees: a pose prior for upright objects seen by a roughly upright camera.

``sign_invariant`` (not the paper's) also offers -q as a target, i.e. the loss becomes
(1 - |q_pred . q|) / 2: q and -q are one rotation, and the q0 = 0 seam of the hemisphere
rule, where the target jumps from q to -q, disappears.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np
import torch

from bbpose_ros.core.geometry.boxes import box_centres
from bbpose_ros.core.geometry.rotations import egocentric_to_allocentric, matrix_to_quat_wxyz
from bbpose_ros.core.nets.images import images_to_input
from bbpose_ros.core.nets.qnet import QNet, QNetConfig
from bbpose_ros.core.nets.quaternion import multi_hypothesis_loss, symmetric_dot_product_loss
from bbpose_ros.core.synth.placement import viewpoint_angles
from bbpose_ros.core.training.augment import augment_batch
from bbpose_ros.core.training.crop_cache import instance_split
from bbpose_ros.core.training.device import TrainingDevice
from bbpose_ros.core.training.settings import QNetTrainSettings

if TYPE_CHECKING:
    from bbpose_ros.core.data.models import ObjectModel
    from bbpose_ros.core.training.cache import TrainingCache
    from bbpose_ros.core.training.crop_cache import CropCache


class QNetBatches:
    """
    Draws Q-Net training batches from a TrainingCache or a CropCache.

    Args:
        cache: TrainingCache (crops cut from rendered scenes, jittered per draw) or CropCache
            (crops rendered around already jittered boxes).
        config: QNetConfig of the network (objects, crop size, context, target).
        models: {name: ObjectModel} for the symmetry transforms.
        settings: QNetTrainSettings.
        seed: seed of the draws.

    """

    def __init__(self, cache: TrainingCache | CropCache, config: QNetConfig,
                 models: Mapping[str, ObjectModel], settings: QNetTrainSettings,
                 seed: int) -> None:
        self.cache, self.config, self.settings = cache, config, settings
        upright = None if settings.max_inplane_deg is None else \
            np.abs(inplane_deg(cache)) <= settings.max_inplane_deg
        self.net_index, self.train_ids, self.val_ids = instance_split(cache, config.objects,
                                                                      settings, upright)
        self.symmetries, self.symmetry_valid = symmetry_rotations(
            [models[n] for n in config.objects])
        self.rng = np.random.default_rng(seed)
        self.generator = torch.Generator().manual_seed(seed)

    def train_batch(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """(crops (B, 3, S, S) float, object index (B,), candidates (B, K, 4), valid (B, K))."""
        ids = self.rng.choice(self.train_ids, self.settings.batch)
        return self.make(ids, self.rng, self.settings.box_sigma, self.settings.augment_strength)

    def make(self, ids: np.ndarray, rng: np.random.Generator, box_sigma: float,
             strength: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Build a batch of the instances ``ids``: ``box_sigma`` jitter, ``strength`` augmented."""
        cache, config = self.cache, self.config
        crops, boxes = cache.input_crops(ids, rng, box_sigma, config.crop_size, config.context)
        images = images_to_input(torch.from_numpy(crops))
        images = augment_batch(images, self.generator, strength, self.settings.augment)
        rotations = cache.rotation[ids].astype(float)
        if config.rotation_target == 'allocentric':
            rotations = egocentric_to_allocentric(rotations,
                                                  cache.camera.rays(box_centres(boxes)))
        index = self.net_index[ids]
        candidates = rotations[:, None] @ self.symmetries[index]
        quats = matrix_to_quat_wxyz(candidates)
        valid = self.symmetry_valid[index]
        if self.settings.sign_invariant:
            quats = np.concatenate([quats, -quats], axis=1)
            valid = np.concatenate([valid, valid], axis=1)
        return (images.contiguous(memory_format=torch.channels_last),
                torch.from_numpy(index), torch.from_numpy(quats).float(),
                torch.from_numpy(valid))


def inplane_deg(cache: TrainingCache | CropCache) -> np.ndarray:
    """(m,) roll of each cached instance about the ray through its amodal box centre, deg."""
    rotations = egocentric_to_allocentric(cache.rotation.astype(float),
                                          cache.camera.rays(box_centres(cache.box_uv)))
    return np.degrees(viewpoint_angles(rotations)[2])


def symmetry_rotations(models: Sequence[ObjectModel]) -> tuple[np.ndarray, np.ndarray]:
    """
    Symmetry rotations of each object, identity first, padded to a common count K.

    Returns (objects, K, 3, 3) rotations (padding: identity) and (objects, K) bool valid.
    """
    count = max(len(m.symmetry_transforms) for m in models)
    rotations = np.tile(np.eye(3), (len(models), count, 1, 1))
    valid = np.zeros((len(models), count), dtype=bool)
    for k, model in enumerate(models):
        transforms = model.symmetry_transforms
        rotations[k, :len(transforms)] = transforms[:, :3, :3]
        valid[k, :len(transforms)] = True
    return rotations, valid


def qnet_loss(outputs: tuple[torch.Tensor, torch.Tensor], candidates: torch.Tensor,
              valid: torch.Tensor) -> torch.Tensor:
    """
    Per-crop training loss (B,): the symmetric Dot Product Loss, or winner-takes-all.

    ``outputs`` are ``QNet.hypotheses``' (quaternions (B, H, 4), scores (B, H)).
    """
    quats, scores = outputs
    if quats.shape[1] == 1:
        return symmetric_dot_product_loss(quats[:, 0], candidates, valid)
    return multi_hypothesis_loss(quats, scores, candidates, valid)


def qnet_step(network: QNet, optimizer: torch.optim.Optimizer, batches: QNetBatches,
              device: TrainingDevice) -> float:
    """One optimisation step on ``device``; returns the batch's mean loss."""
    images, index, candidates, valid = device.put(*batches.train_batch())
    outputs = device.forward(network.hypotheses, images, index)
    return device.minimise(optimizer, qnet_loss(outputs, candidates, valid).mean())


def qnet_validation(network: QNet, batches: QNetBatches, device: TrainingDevice,
                    count: int = 512, seed: int = 12345) -> dict[str, float]:
    """Score held-out scenes: loss, median rotation error (deg), share under 15 deg."""
    rng = np.random.default_rng(seed)
    ids = rng.choice(batches.val_ids, min(count, len(batches.val_ids)), replace=False)
    network.eval()
    with torch.inference_mode():
        images, index, candidates, valid = device.put(
            *batches.make(ids, rng, batches.settings.box_sigma, 0.0))
        loss = symmetric_dot_product_loss(network(images, index), candidates, valid).cpu()
    # Dot Product Loss L = (1 - cos(theta / 2)) / 2 for a rotation error theta.
    angles = np.degrees(2 * np.arccos(np.clip(np.abs(1 - 2 * loss.numpy()), 0, 1)))
    return {'val_loss': float(loss.mean()), 'val_median_deg': float(np.median(angles)),
            'val_acc15': float(np.mean(angles < 15))}
