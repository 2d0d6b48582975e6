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
Detector training on a rendered cache: CenterNet heatmaps and log box sides.

Targets on the stride-8 grid: for each instance with visible fraction >= ``min_visib`` a
Gaussian peak at its amodal box centre in its class channel (sigma grows with the box), and
the log distances from each cell near the centre to the four amodal box sides. Losses:
CenterNet's penalty-reduced focal loss on the heatmap, L1 on the log sides weighted by the
Gaussian, both per instance. Training steps see random ``train_crop`` windows (width,
height; multiples of 16, offsets on the stride-8 grid) of the cached inputs: the network is
fully convolutional, and a window costs only its share of the frame. Validation on whole
held-out scenes: recall at IoU 0.5 and the box side errors (per-side error / box size) that
Q-Net's training jitter should match.
"""

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
import torch
import torch.nn.functional as F

from bbpose_ros.core.geometry.boxes import box_iou
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.nets.detector import CenterBoxNet, decode, DetectorConfig
from bbpose_ros.core.nets.images import images_to_input
from bbpose_ros.core.training.augment import augment_batch
from bbpose_ros.core.training.cache import TrainingCache
from bbpose_ros.core.training.device import TrainingDevice
from bbpose_ros.core.training.settings import DetectorTrainSettings


def detector_classes(config: DetectorConfig, cache: TrainingCache) -> np.ndarray:
    """(K,) the detector's class index of each cache object index, -1 where it has none."""
    return np.array([config.objects.index(n) if n in config.objects else -1
                     for n in cache.objects])


def to_input_pixels(boxes_uv: npt.ArrayLike, config: DetectorConfig,
                    camera: CameraIntrinsics) -> np.ndarray:
    """(M, 4) full-frame continuous-pixel boxes -> the network input's (``input_size``)."""
    scale = np.array([config.input_size[0] / camera.width,
                      config.input_size[1] / camera.height] * 2)
    return (np.asarray(boxes_uv, dtype=float) + 0.5) * scale - 0.5


class DetectorBatches:
    """Draws detector batches (images, heatmap, sides, side weights) from a TrainingCache."""

    def __init__(self, cache: TrainingCache, config: DetectorConfig,
                 settings: DetectorTrainSettings, seed: int) -> None:
        self.cache, self.config, self.settings = cache, config, settings
        if tuple(cache.input_size) != tuple(config.input_size):
            raise ValueError(f'cache input size {cache.input_size} != {config.input_size}')
        self.class_of = detector_classes(config, cache)
        scenes = len(cache.images)
        val_start = int(scenes * (1 - settings.val_fraction))
        self.train_scenes = np.arange(val_start)
        self.val_scenes = np.arange(val_start, scenes)
        self.by_scene = [np.flatnonzero((cache.scene == s) & (cache.visib >= settings.min_visib)
                                        & (self.class_of[cache.object] >= 0))
                         for s in range(scenes)]
        self.rng = np.random.default_rng(seed)
        self.generator = torch.Generator().manual_seed(seed)

    def input_boxes(self, ids: np.ndarray) -> np.ndarray:
        """(M, 4) amodal boxes of instances ``ids`` in network-input continuous pixels."""
        return to_input_pixels(self.cache.box_uv[ids], self.config, self.cache.camera)

    def train_batch(self) -> tuple[torch.Tensor, ...]:
        """Images (B, 3, H, W) float, heatmap (B, C, h, w), sides (B, 4, h, w), weight."""
        scenes = self.rng.choice(self.train_scenes, self.settings.batch)
        return self.make(scenes, self.settings.augment_strength, self.settings.train_crop)

    def make(self, scenes: Sequence[int] | np.ndarray, strength: float,
             window: tuple[int, int] | None = None) -> tuple[torch.Tensor, ...]:
        """Build the batch of ``scenes``, augmented at ``strength``, cut to ``window`` (w, h)."""
        full_w, full_h = self.config.input_size
        width, height = window or (full_w, full_h)
        stride = self.config.stride
        offsets = np.stack([self.rng.integers(0, (full_w - width) // stride + 1, len(scenes)),
                            self.rng.integers(0, (full_h - height) // stride + 1, len(scenes))],
                           axis=1) * stride
        images = np.stack([self.cache.images[s, y:y + height, x:x + width]
                           for s, (x, y) in zip(scenes, offsets)])
        images = images_to_input(torch.from_numpy(images))
        images = augment_batch(images, self.generator, strength, self.settings.augment)
        targets = [self._targets(self.by_scene[s], offset, width, height)
                   for s, offset in zip(scenes, offsets)]
        heat, sides, weight = (torch.from_numpy(np.stack(t)) for t in zip(*targets))
        return images.contiguous(memory_format=torch.channels_last), heat, sides, weight

    def _targets(self, ids, offset, width, height):
        """Heatmap, log sides and weights of instances ``ids`` in a window at ``offset``."""
        stride = self.config.stride
        h, w = height // stride, width // stride
        heat = np.zeros((len(self.config.objects), h, w), dtype=np.float32)
        sides = np.zeros((4, h, w), dtype=np.float32)
        weight = np.zeros((h, w), dtype=np.float32)
        cols = np.arange(w) * stride + (stride - 1) / 2.0
        rows = np.arange(h) * stride + (stride - 1) / 2.0
        grid_v, grid_u = np.meshgrid(rows, cols, indexing='ij')
        boxes = self.input_boxes(ids) - np.tile(offset, 2)
        # Bigger objects first, so a small object's box wins where regions overlap.
        order = np.argsort(-np.prod(boxes[:, 2:] - boxes[:, :2], axis=1))
        for box, obj in zip(boxes[order], self.cache.object[ids][order]):
            centre = (box[:2] + box[2:]) / 2
            if not (0 <= centre[0] < width and 0 <= centre[1] < height):
                continue
            sigma = max(0.6, min(box[2] - box[0], box[3] - box[1]) / stride / 6.0)
            gx = np.exp(-((cols - centre[0]) / stride) ** 2 / (2 * sigma ** 2))
            gy = np.exp(-((rows - centre[1]) / stride) ** 2 / (2 * sigma ** 2))
            gauss = gy[:, None] * gx[None, :]
            peak = np.unravel_index(np.argmax(gauss), gauss.shape)
            gauss[peak] = 1.0
            channel = self.class_of[obj]
            heat[channel] = np.maximum(heat[channel], gauss)
            region = gauss > 0.3
            dist = np.stack([grid_u - box[0], grid_v - box[1], box[2] - grid_u,
                             box[3] - grid_v])
            sides[:, region] = np.log(np.maximum(dist[:, region], 1.0) / stride)
            weight[region] = gauss[region]
        return heat, sides, weight


def focal_loss(logits: torch.Tensor, target: torch.Tensor,
               counted: torch.Tensor | None = None) -> torch.Tensor:
    """
    Compute CenterNet's penalty-reduced focal loss (alpha 2, beta 4) per peak.

    ``counted`` (bool, the shape of ``target``) leaves the cells where it is False out of
    the background term: regions whose content is unknown (an untrusted pseudo label).
    """
    prob = torch.sigmoid(logits).clamp(1e-4, 1 - 1e-4)
    positive = target.eq(1.0)
    pos_loss = -torch.log(prob) * (1 - prob) ** 2 * positive
    negative = ~positive if counted is None else ~positive & counted
    neg_loss = -torch.log(1 - prob) * prob ** 2 * (1 - target) ** 4 * negative
    return (pos_loss.sum() + neg_loss.sum()) / positive.sum().clamp_min(1)


def detector_loss(outputs: Sequence[torch.Tensor], targets: Sequence[torch.Tensor],
                  box_weight: float) -> torch.Tensor:
    """
    Heatmap focal loss + weighted L1 on the log box sides, for one batch.

    ``outputs`` are the network's (heatmap logits, log sides), ``targets`` the batch's
    (heatmap, sides, weight) (``DetectorBatches.make`` without the images).
    """
    heat_logits, side_pred = outputs
    heat, sides, weight = targets
    l1 = (F.l1_loss(side_pred, sides, reduction='none').sum(dim=1) * weight).sum()
    return focal_loss(heat_logits, heat) + box_weight * l1 / weight.sum().clamp_min(1)


def detector_step(network: CenterBoxNet, optimizer: torch.optim.Optimizer,
                  batches: DetectorBatches, device: TrainingDevice) -> float:
    """One optimisation step on ``device``; returns the batch loss."""
    images, *targets = device.put(*batches.train_batch())
    loss = detector_loss(device.forward(network, images), targets, batches.settings.box_weight)
    return device.minimise(optimizer, loss)


def detector_validation(network: CenterBoxNet, batches: DetectorBatches,
                        device: TrainingDevice, score_threshold: float = 0.3,
                        max_scenes: int = 200) -> dict[str, float]:
    """
    Score held-out scenes: loss, recall at IoU 0.5, and side errors of the matched boxes.

    ``side_sigma`` is the RMS of (predicted side - true side) / true box width or height over
    the detections that found their instance (IoU >= 0.5): the quantity
    ``QNetTrainSettings.box_sigma`` uses to jitter Q-Net's crops (a missed instance gets no
    usable pose whatever the crop).
    """
    network.eval()
    scenes = batches.val_scenes[:max_scenes]
    found, total, errors, losses = 0, 0, [], []
    with torch.inference_mode():
        for chunk in np.array_split(scenes, max(1, len(scenes) // 16)):
            images, *targets = device.put(*batches.make(chunk, 0.0))
            outputs = network(images)
            losses.append(float(detector_loss(outputs, targets, batches.settings.box_weight)))
            heat, sides = (x.cpu() for x in outputs)
            for k, scene in enumerate(chunk):
                ids = batches.by_scene[scene]
                classes, _, boxes = decode(heat[k], sides[k], batches.config.stride,
                                           score_threshold, 1)
                truth = batches.input_boxes(ids)
                for j, true_box in zip(ids, truth):
                    total += 1
                    hit = classes == batches.class_of[batches.cache.object[j]]
                    if not hit.any():
                        continue
                    box = boxes[hit][0]
                    if box_iou(box, true_box)[0, 0] >= 0.5:
                        found += 1
                        size = np.concatenate([true_box[2:] - true_box[:2]] * 2)
                        errors.append((box - true_box) / size)
    errors = np.array(errors).reshape(-1, 4)
    sigma = float(np.sqrt(np.mean(errors ** 2))) if len(errors) else 0.0
    return {'val_loss': float(np.mean(losses)), 'val_recall50': found / max(total, 1),
            'side_sigma': sigma}
