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
A compact CenterNet-style 2D detector that returns amodal boxes, trained on CPU from renders.

Design, and why:

* The 640x480 frame is downscaled to 320x240 (``input_size``): LM-O objects are large
  enough to stay well resolved after halving, and the convolutions cost a quarter.
* Features down to stride 16 and one top-down merge back to stride 8 (a 40x30 grid), from
  one of two backbones: 'lite0', EfficientNet-Lite0's ImageNet-pretrained blocks (features
  learned on photographs carry over from renders to camera images), or 'scratch', a plain
  stride-2 conv stack (BN + ReLU) with one dilated conv for a receptive field larger than
  the biggest object. No anchors and no NMS beyond a 3x3 max-pool: one class heatmap per
  object, as in CenterNet (Zhou et al. 2019), since each object name is a class of its own.
* Boxes are regressed FCOS-style as the four distances (left, top, right, bottom) from the
  peak cell's centre to the sides of the AMODAL box, in log space (scale-free L1). The
  heatmap peak sits at the amodal box centre, so a half-hidden object still gets its full
  box, which the Bounding Box Equation needs.
* Sized for the detector's budget on 2 CPU cores (``bbpose bench`` checks it).
* An optional second stage, as in MTCNN's cascade (``core.nets.verifier``): the
  ``candidates`` highest peaks of each class are re-scored by a small classifier on a crop
  of their box, which learns the false peaks the heatmap ranks high.
"""

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn
import torch.nn.functional as F

from bbpose_ros.core.nets.config_dict import ConfigDict
from bbpose_ros.core.nets.efficientnet_lite import BACKBONES, BLOCK_CHANNELS, EfficientNetLite0
from bbpose_ros.core.nets.images import normalize_input
from bbpose_ros.core.nets.verifier import CandidateVerifier

HEATMAP_PRIOR = 0.05   # initial peak probability (CenterNet's focal-loss bias init)
# Lite0 blocks whose outputs the 'lite0' detector merges: stride 8 (40 ch), stride 16 (112 ch).
LITE0_TAPS = (4, 10)


@dataclass(frozen=True)
class DetectorConfig(ConfigDict):
    """
    Architecture of the detector (stored in its weight file).

    Attributes:
        objects: class names, one heatmap channel each, in this order.
        input_size: (width, height) the frame is resized to before the network.
        channels: widths of the stride 2, 4, 8 and 16 stages ('scratch' backbone only).
        stride: output grid stride in input pixels (fixed by the architecture: 8).
        verifier_channels: widths of the second stage's four conv stages; () (also files
            without this field): no second stage, the heatmap peaks are the detections.
        verifier_crop_size: side of the second stage's crops, in pixels.
        verifier_context: crop side / longest side of the candidate's box.
        candidates: peaks per class the second stage re-scores.
        candidate_threshold: lowest heatmap peak probability passed to the second stage.
        backbone: 'scratch' (the plain conv stack of ``channels``, trained from random
            weights; older files) or 'lite0' (EfficientNet-Lite0's first 11 blocks,
            initialised from ImageNet when trained, with a head of ``head_channels``).
        head_channels: width of the 'lite0' head's merged stride-8 features.

    """

    objects: tuple[str, ...]
    input_size: tuple[int, int] = (320, 240)
    channels: tuple[int, ...] = (16, 32, 48, 96)
    stride: int = 8
    verifier_channels: tuple[int, ...] = ()
    verifier_crop_size: int = 32
    verifier_context: float = 1.2
    candidates: int = 3
    candidate_threshold: float = 0.02
    backbone: str = 'scratch'
    head_channels: int = 64

    def __post_init__(self) -> None:
        if self.backbone not in BACKBONES:
            raise ValueError(f'unknown detector backbone {self.backbone!r}; '
                             f'choose one of {", ".join(BACKBONES)}')


def _conv(cin, cout, stride=1, dilation=1):
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, stride=stride, padding=dilation, dilation=dilation,
                  bias=False),
        nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


class CenterBoxNet(nn.Module):
    """
    Class heatmaps and amodal box sides on a stride-8 grid.

    ``forward(images)``: (N, 3, H, W) float RGB in 0..1 at ``input_size`` ->
    (heatmap logits (N, C, H/8, W/8), log box sides (N, 4, H/8, W/8)).

    Box sides are log(distance / stride) from each cell centre to the left, top, right and
    bottom edges of the amodal box, in input pixels. ``verifier`` is the second stage (a
    CandidateVerifier, run separately on crops) or None.
    """

    def __init__(self, config: DetectorConfig) -> None:
        super().__init__()
        self.config = config
        if config.backbone == 'lite0':
            width = config.head_channels
            self.trunk = EfficientNetLite0(blocks=LITE0_TAPS[-1] + 1)
            self.lateral_fine = nn.Conv2d(BLOCK_CHANNELS[LITE0_TAPS[0]], width, 1)
            self.lateral = nn.Conv2d(BLOCK_CHANNELS[LITE0_TAPS[1]], width, 1)
            self.merge = nn.Sequential(_conv(width, width), _conv(width, width))
        else:
            c1, c2, c3, c4 = config.channels
            width = c3
            self.stage1 = _conv(3, c1, stride=2)
            self.stage2 = _conv(c1, c2, stride=2)
            self.stage3 = nn.Sequential(_conv(c2, c3, stride=2), _conv(c3, c3))
            self.stage4 = nn.Sequential(_conv(c3, c4, stride=2), _conv(c4, c4),
                                        _conv(c4, c4, dilation=2))
            self.lateral = nn.Conv2d(c4, c3, 1)
            self.merge = _conv(c3, c3)
        self.heatmap = nn.Conv2d(width, len(config.objects), 1)
        self.box = nn.Conv2d(width, 4, 1)
        prior = torch.tensor(HEATMAP_PRIOR)
        nn.init.constant_(self.heatmap.bias, float(torch.log(prior / (1 - prior))))
        nn.init.zeros_(self.box.bias)
        self.verifier = None
        if config.verifier_channels:
            self.verifier = CandidateVerifier(config.verifier_channels, len(config.objects),
                                              config.verifier_crop_size)

    def forward(self, images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Heatmap logits and log box sides on the stride-8 grid."""
        features = self.features(images)
        return self.heatmap(features), self.box(features)

    def features(self, images: torch.Tensor) -> torch.Tensor:
        """(N, width, H/8, W/8): the merged stride-8 features both 1x1 heads read."""
        if self.config.backbone == 'lite0':
            fine, coarse = self.trunk.forward_features(images, LITE0_TAPS)
            fine, coarse = self.lateral_fine(fine), self.lateral(coarse)
        else:
            fine = self.stage3(self.stage2(self.stage1(normalize_input(images))))
            coarse = self.lateral(self.stage4(fine))
        up = F.interpolate(coarse, size=fine.shape[-2:], mode='nearest')
        return self.merge(fine + up)


class PeakOutputs(nn.Module):
    """A CenterBoxNet whose outputs are its heatmap peaks (``peaks``), for a runner's graph."""

    def __init__(self, network: CenterBoxNet, count: int) -> None:
        super().__init__()
        self.network = network
        self.count = count

    def forward(self, images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``peaks`` of the network's outputs for (N, 3, H, W) images."""
        return peaks(*self.network(images), self.count)


def peaks(heatmap_logits: torch.Tensor, box_log: torch.Tensor,
          count: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """
    Find the ``count`` highest local maxima (3x3) of every class heatmap, with box sides.

    Torch operations only, so that it runs inside an exported graph (``PeakOutputs``).

    Args:
        heatmap_logits: (N, C, h, w) tensor.
        box_log: (N, 4, h, w) tensor of log(side distance / stride).
        count: peaks per class (at most h * w).

    Returns:
        scores (N, C, count) peak probabilities, highest first (0 past the last maximum);
        cells (N, C, count) long flat cell indices (row * w + col); sides (N, 4, C * count)
        distances to the left, top, right and bottom box sides in grid cells, class-major.

    """
    heat = torch.sigmoid(heatmap_logits)
    heat = heat * (heat == F.max_pool2d(heat, 3, stride=1, padding=1))
    batch = heat.shape[0]
    scores, cells = heat.flatten(2).topk(count, dim=2)
    sides = torch.exp(box_log.flatten(2)).gather(
        2, cells.reshape(batch, 1, -1).expand(-1, 4, -1))
    return scores, cells, sides


def peak_boxes(scores: np.ndarray, cells: np.ndarray, sides: np.ndarray, width: int,
               stride: int, score_threshold: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Boxes of one image's peaks (numpy ``peaks`` outputs of that image) above a threshold.

    Args:
        scores: (C, K) peak probabilities.
        cells: (C, K) flat cell indices.
        sides: (4, C * K) side distances in grid cells.
        width: heatmap width in cells.
        stride: grid stride in input pixels.
        score_threshold: lowest peak probability kept.

    Returns:
        (class_index (M,) int, score (M,) float, box (M, 4) [u_min, v_min, u_max, v_max] in
        the network input's continuous pixel coordinates), highest score first.

    """
    classes = np.repeat(np.arange(scores.shape[0]), scores.shape[1])
    scores, cells = scores.reshape(-1), cells.reshape(-1)
    keep = np.flatnonzero(scores >= score_threshold)
    keep = keep[np.argsort(-scores[keep], kind='stable')]
    centre_u = (cells[keep] % width) * stride + (stride - 1) / 2.0
    centre_v = (cells[keep] // width) * stride + (stride - 1) / 2.0
    left, top, right, bottom = sides[:, keep] * stride
    boxes = np.stack([centre_u - left, centre_v - top, centre_u + right, centre_v + bottom],
                     axis=1)
    return classes[keep], scores[keep], boxes


def decode(heatmap_logits: torch.Tensor, box_log: torch.Tensor, stride: int,
           score_threshold: float,
           max_per_class: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Peaks of the class heatmaps and their boxes, for one image (``peaks`` + ``peak_boxes``).

    Args:
        heatmap_logits: (C, h, w) tensor.
        box_log: (4, h, w) tensor of log(side distance / stride).
        stride: grid stride in input pixels.
        score_threshold: lowest peak probability kept.
        max_per_class: most peaks kept per class.

    Returns:
        numpy (class_index (K,) int, score (K,) float, box (K, 4)) as ``peak_boxes``.

    """
    height, width = heatmap_logits.shape[-2:]
    outputs = peaks(heatmap_logits[None], box_log[None], min(max_per_class, height * width))
    return peak_boxes(*(x[0].numpy() for x in outputs), width, stride, score_threshold)
