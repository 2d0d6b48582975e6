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
Training data, loss and validation of the detector's second stage (``nets.verifier``).

The trained heatmap stage, frozen, runs once over the cached scenes; each of its candidate
boxes (the ``mined_per_class`` highest peaks of every class) is cut as the detector cuts it
at run time and labelled with the class of the ground-truth amodal box it overlaps most if
their IoU is at least ``positive_iou``, else background; the side corrections to that
true box are its regression target. ``positive_iou`` is below the 0.5 a detection needs
because the corrected box, not the candidate's, is reported (MTCNN trains its box
regression on such "part" boxes too). The ground-truth boxes themselves, jittered, add
positives. Batches mix positives and negatives in a fixed proportion, with the detector's
photometric augmentation. The loss: cross-entropy + ``box_weight`` x smooth L1 of the
corrections of the positives.
"""

from collections.abc import Sequence

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from bbpose_ros.core.geometry.boxes import box_iou, jitter_boxes
from bbpose_ros.core.nets.crops import extract_crops, square_boxes
from bbpose_ros.core.nets.detector import CenterBoxNet, decode
from bbpose_ros.core.nets.images import images_to_input
from bbpose_ros.core.nets.verifier import CandidateVerifier
from bbpose_ros.core.training.augment import augment_batch
from bbpose_ros.core.training.cache import TrainingCache
from bbpose_ros.core.training.detector_training import detector_classes, to_input_pixels
from bbpose_ros.core.training.device import TrainingDevice
from bbpose_ros.core.training.settings import VerifierTrainSettings


class CandidateCrops:
    """
    Labelled second-stage crops mined from a TrainingCache with a detector's first stage.

    Attributes:
        crops: (M, S, S, 3) uint8, cut from the cached network inputs.
        labels: (M,) int: 0 background, k + 1 the detector's class k.
        corrections: (M, 4) float32 side corrections to the true box (see
            ``CandidateVerifier``), zero for background.
        scene: (M,) int scene index in the cache.
        scenes: number of scenes in the cache.

    """

    def __init__(self, network: CenterBoxNet, cache: TrainingCache,
                 settings: VerifierTrainSettings, seed: int, device: TrainingDevice,
                 progress: bool = True, chunk: int = 64) -> None:
        config = network.config
        class_of = detector_classes(config, cache)
        rng = np.random.default_rng(seed)
        parts = []
        network.eval()
        starts = range(0, len(cache.images), chunk)
        for start in tqdm(starts, desc='mining candidates', unit='chunk', disable=not progress):
            images = cache.images[start:start + chunk]
            with torch.inference_mode():
                outputs = network(*device.put(images_to_input(torch.from_numpy(images))))
            heat, sides = (x.cpu() for x in outputs)
            for k, image in enumerate(images):
                scene = start + k
                ids = np.flatnonzero((cache.scene == scene) & (cache.visib >= settings.min_visib)
                                     & (class_of[cache.object] >= 0))
                truth = to_input_pixels(cache.box_uv[ids], config, cache.camera)
                truth_class = class_of[cache.object[ids]]
                classes, _, boxes = decode(heat[k], sides[k], config.stride,
                                           config.candidate_threshold, settings.mined_per_class)
                boxes = np.concatenate([boxes,
                                        jitter_boxes(truth, rng, settings.box_sigma)])
                squares = square_boxes(boxes, config.verifier_context)
                labels, corrections = candidate_targets(boxes, squares, truth, truth_class,
                                                        settings.positive_iou)
                parts.append((extract_crops(image, squares, config.verifier_crop_size),
                              labels, corrections, np.full(len(labels), scene)))
        self.crops, self.labels, self.corrections, self.scene = (
            np.concatenate(p) for p in zip(*parts))
        self.scenes = len(cache.images)


def candidate_targets(boxes: np.ndarray, squares: np.ndarray, truth: np.ndarray,
                      truth_class: np.ndarray,
                      positive_iou: float) -> tuple[np.ndarray, np.ndarray]:
    """
    Labels (K,) and side corrections (K, 4) of candidate ``boxes`` cut as ``squares``.

    A box overlapping a true box with IoU >= ``positive_iou`` gets 1 + its class and the
    corrections to it (the one it overlaps most); the others 0 and zeros.
    """
    labels = np.zeros(len(boxes), dtype=np.int64)
    corrections = np.zeros((len(boxes), 4), dtype=np.float32)
    if len(boxes) and len(truth):
        overlap = box_iou(boxes, truth)
        best = overlap.argmax(axis=1)
        hit = overlap.max(axis=1) >= positive_iou
        labels[hit] = truth_class[best[hit]] + 1
        side = squares[hit, 2:3] - squares[hit, 0:1]
        corrections[hit] = (truth[best[hit]] - boxes[hit]) / side
    return labels, corrections


class VerifierBatches:
    """Draws balanced, augmented batches of CandidateCrops; the last scenes validate."""

    def __init__(self, candidates: CandidateCrops, settings: VerifierTrainSettings,
                 seed: int) -> None:
        self.candidates, self.settings = candidates, settings
        held_out = candidates.scene >= int(candidates.scenes * (1 - settings.val_fraction))
        train = np.flatnonzero(~held_out)
        self.positives = train[candidates.labels[train] > 0]
        self.negatives = train[candidates.labels[train] == 0]
        self.val = np.flatnonzero(held_out)
        if not len(self.positives) or not len(self.negatives):
            raise ValueError('the training scenes gave no positive or no negative candidate')
        self.rng = np.random.default_rng(seed)
        self.generator = torch.Generator().manual_seed(seed)

    def train_batch(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(crops (B, 3, S, S) float, labels (B,) long, corrections (B, 4)), augmented."""
        count = int(round(self.settings.batch * self.settings.positive_fraction))
        ids = np.concatenate([self.rng.choice(self.positives, count),
                              self.rng.choice(self.negatives, self.settings.batch - count)])
        crops, labels, corrections = self.batch(ids)
        crops = augment_batch(crops, self.generator, self.settings.augment_strength,
                              self.settings.augment)
        return crops, labels, corrections

    def batch(self, ids: np.ndarray) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(crops (n, 3, S, S) float, labels (n,) long, corrections (n, 4)) of ``ids``."""
        return (images_to_input(torch.from_numpy(self.candidates.crops[ids])),
                torch.from_numpy(self.candidates.labels[ids]),
                torch.from_numpy(self.candidates.corrections[ids]))


def verifier_loss(outputs: Sequence[torch.Tensor], targets: Sequence[torch.Tensor],
                  settings: VerifierTrainSettings) -> torch.Tensor:
    """
    Cross-entropy + ``box_weight`` x smooth L1 of the positives' side corrections.

    ``outputs`` are ``CandidateVerifier.outputs``' (class logits, corrections), ``targets``
    the batch's (labels, corrections).
    """
    logits, predicted = outputs
    labels, corrections = targets
    positive = labels > 0
    box = F.smooth_l1_loss(predicted[positive], corrections[positive], beta=0.05,
                           reduction='sum') / max(int(positive.sum()), 1)
    return F.cross_entropy(logits, labels, label_smoothing=settings.label_smoothing) \
        + settings.box_weight * box


def verifier_step(verifier: CandidateVerifier, optimizer: torch.optim.Optimizer,
                  batches: VerifierBatches, device: TrainingDevice) -> float:
    """One optimisation step on ``device``; returns the batch loss."""
    crops, *targets = device.put(*batches.train_batch())
    loss = verifier_loss(device.forward(verifier.outputs, crops), targets, batches.settings)
    return device.minimise(optimizer, loss)


def verifier_validation(verifier: CandidateVerifier, batches: VerifierBatches,
                        device: TrainingDevice, max_crops: int = 20000) -> dict[str, float]:
    """
    Held-out scenes: loss, accuracy, positives given their class, side error of the positives.

    ``val_side_error``: mean |predicted - true| side correction of the positives, as a
    fraction of the crop side (``val_side_error_before``: the candidates' own).
    """
    verifier.eval()
    ids = batches.val[:max_crops]
    losses, predicted, labels, side_errors, before = [], [], [], [], []
    with torch.inference_mode():
        for chunk in np.array_split(ids, max(1, len(ids) // 1024)):
            crops, *targets = device.put(*batches.batch(chunk))
            outputs = verifier.outputs(crops)
            losses.append(float(verifier_loss(outputs, targets, batches.settings)) * len(chunk))
            logits, corrections = (x.cpu() for x in outputs)
            truth_labels, truth = (x.cpu() for x in targets)
            positive = truth_labels > 0
            predicted.append(logits.argmax(dim=1).numpy())
            labels.append(truth_labels.numpy())
            side_errors.append((corrections - truth)[positive].abs().numpy())
            before.append(truth[positive].abs().numpy())
    predicted, labels = np.concatenate(predicted), np.concatenate(labels)
    positive = labels > 0
    return {'val_loss': sum(losses) / max(len(labels), 1),
            'val_accuracy': float(np.mean(predicted == labels)),
            'val_positive_recall': float(np.mean(predicted[positive] == labels[positive])),
            'val_side_error': float(np.concatenate(side_errors).mean()),
            'val_side_error_before': float(np.concatenate(before).mean())}
