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
Q-Net: a small CNN that regresses one unit quaternion (wxyz) from a square object crop.

The paper's shape ('scratch' backbone): 3x3 convolutions (stride 1) each followed by 2x2
max pooling (stride 2), then fully connected layers, then the q-normalization layer. Batch
normalisation after each convolution speeds up CPU training; at inference it is folded into
the convolution (or fused by ONNX Runtime). Widths (``QNetConfig.channels``, stored in each
weight file) are kept small so that all the crops of a frame run within Q-Net's budget on
2 CPU cores.

Options (``QNetConfig``), the paper's version being the default where it has one:

* ``crop_size`` 48 (paper) or larger, e.g. 64 (one more pooling stage is not added: the
  last feature map grows instead);
* ``rotation_target`` 'egocentric' (paper: the model-to-camera rotation) or 'allocentric'
  (rotation relative to the ray through the box centre; see ``rotations.ray_rotation``);
* ``sharing`` 'shared' (one trunk, one 4-output head per object) or 'per_object' (one whole
  network per object, as the paper trains them);
* ``first_stride`` 1 (paper) or 2: the first convolution samples every second pixel instead
  of being followed by a max-pool: three quarters of its multiply-adds go, and with them
  the slowest kernel at inference (its 3 input channels use the vector units poorly);
* ``q_normalization`` True (paper) or False (only for the paper's Fig. 3 comparison);
* ``backbone`` 'scratch' (the paper's small conv stack above, trained from random weights)
  or 'lite0': EfficientNet-Lite0's first 11 blocks (stride 16, ImageNet-pretrained when
  trained, ``core.nets.efficientnet_lite``), a 1x1 reduction to ``channels[-1]`` and the
  same hidden FC layer: features learned on real photographs carry over from renders to
  camera images far better than features learned on renders alone;
* ``hypotheses`` 1 (paper) or H > 1: each head gives H quaternions and H scores, trained
  winner-takes-all (``quaternion.multi_hypothesis_loss``) and the best-scored one is the
  output. One regressed quaternion lands between the views a crop cannot tell apart (a
  front and a back that look alike at 48x48); H of them can each settle on one
  (Rupprecht et al., ICCV 2017; Manhardt et al., ICCV 2019).
"""

from dataclasses import dataclass

import torch
from torch import nn

from bbpose_ros.core.nets.config_dict import ConfigDict
from bbpose_ros.core.nets.efficientnet_lite import (BACKBONES, BLOCK_CHANNELS, BLOCK_STRIDES,
                                                    EfficientNetLite0)
from bbpose_ros.core.nets.images import normalize_input
from bbpose_ros.core.nets.quaternion import QNormalization

ROTATION_TARGETS = ('egocentric', 'allocentric')
LITE0_BLOCKS = 11       # EfficientNet-Lite0 up to stride 16 (112 channels)
LITE0_STRIDE = BLOCK_STRIDES[LITE0_BLOCKS - 1]
SHARING_MODES = ('shared', 'per_object')


@dataclass(frozen=True)
class QNetConfig(ConfigDict):
    """
    Architecture and convention of a Q-Net (all stored in its weight file).

    Attributes:
        objects: object names, one head (or network) each, in this order.
        crop_size: side of the square input crop in pixels.
        context: crop side / longest box side (>= 1 keeps context around the box).
        channels: output channels of the conv + max-pool stages.
        first_stride: stride of the first convolution: 1 (paper), or 2 in place of the
            first max-pool.
        fc_size: width of the hidden fully connected layer.
        rotation_target: 'egocentric' or 'allocentric'.
        sharing: 'shared' or 'per_object'.
        q_normalization: whether the q-normalization layer ends the network.
        dropout: dropout probability after the hidden FC layer (training only).
        hypotheses: quaternions per head; the output is the best-scored one.
        backbone: 'scratch' (conv + max-pool stages of ``channels``) or 'lite0'
            (EfficientNet-Lite0 to stride 16, then a 1x1 convolution to ``channels[-1]``).

    """

    objects: tuple[str, ...]
    crop_size: int = 48
    context: float = 1.2
    channels: tuple[int, ...] = (8, 16, 24, 32)
    first_stride: int = 1
    fc_size: int = 256
    rotation_target: str = 'egocentric'
    sharing: str = 'shared'
    q_normalization: bool = True
    dropout: float = 0.2
    hypotheses: int = 1
    backbone: str = 'scratch'

    def __post_init__(self) -> None:
        if self.rotation_target not in ROTATION_TARGETS:
            raise ValueError(f'rotation_target must be one of {ROTATION_TARGETS}')
        if self.sharing not in SHARING_MODES:
            raise ValueError(f'sharing must be one of {SHARING_MODES}')
        if self.first_stride not in (1, 2):
            raise ValueError(f'first_stride must be 1 or 2, not {self.first_stride}')
        if self.hypotheses < 1:
            raise ValueError(f'hypotheses must be at least 1, not {self.hypotheses}')
        if self.backbone not in BACKBONES:
            raise ValueError(f'backbone must be one of {BACKBONES}, not {self.backbone!r}')
        if self.crop_size % self.feature_stride:
            raise ValueError(f'crop_size {self.crop_size} is not divisible by '
                             f'{self.feature_stride}')

    @property
    def feature_stride(self) -> int:
        """Crop pixels per cell of the last feature map."""
        return LITE0_STRIDE if self.backbone == 'lite0' else 2 ** len(self.channels)


class _LiteFeatures(nn.Module):
    """EfficientNet-Lite0 to stride 16 on 0..1 RGB crops, then 1x1 conv + BN + ReLU."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.trunk = EfficientNetLite0(blocks=LITE0_BLOCKS)
        self.reduce = nn.Sequential(
            nn.Conv2d(BLOCK_CHANNELS[LITE0_BLOCKS - 1], channels, 1, bias=False),
            nn.BatchNorm2d(channels), nn.ReLU(inplace=True))

    def forward(self, crops: torch.Tensor) -> torch.Tensor:
        """(N, 3, S, S) float RGB in 0..1 -> (N, channels, S / 16, S / 16)."""
        return self.reduce(self.trunk.forward_features(crops, (LITE0_BLOCKS - 1,))[0])


def _trunk(config):
    """Feature stages (conv + max-pool, or Lite0), flatten, hidden FC + ReLU + dropout."""
    side = config.crop_size // config.feature_stride
    if config.backbone == 'lite0':
        width = config.channels[-1]
        return nn.Sequential(_LiteFeatures(width), nn.Flatten(),
                             nn.Linear(width * side * side, config.fc_size),
                             nn.ReLU(inplace=True), nn.Dropout(config.dropout))
    layers, width = [], 3
    for stage, channels in enumerate(config.channels):
        strided = stage == 0 and config.first_stride == 2
        layers += [nn.Conv2d(width, channels, 3, stride=2 if strided else 1, padding=1,
                             bias=False),
                   nn.BatchNorm2d(channels), nn.ReLU(inplace=True)]
        layers += [] if strided else [nn.MaxPool2d(2)]
        width = channels
    layers += [nn.Flatten(), nn.Linear(width * side * side, config.fc_size),
               nn.ReLU(inplace=True), nn.Dropout(config.dropout)]
    return nn.Sequential(*layers)


class QNet(nn.Module):
    """
    Q-Net for one or several objects.

    ``forward(crops, object_index)``: crops (N, 3, S, S) float RGB in 0..1, object_index (N,)
    long (position in ``config.objects``) -> (N, 4) quaternions (wxyz; unit length when
    ``config.q_normalization``).
    """

    def __init__(self, config: QNetConfig) -> None:
        super().__init__()
        self.config = config
        count = len(config.objects)
        trunks = 1 if config.sharing == 'shared' else count
        self.trunks = nn.ModuleList([_trunk(config) for _ in range(trunks)])
        # One head per object (rows w k .. w k + w - 1): a quaternion, or H quaternions then
        # H scores. With per_object trunks, head k only ever sees trunk k's features, so each
        # object has a whole network of its own.
        self.head_width = 4 if config.hypotheses == 1 else 5 * config.hypotheses
        self.head = nn.Linear(config.fc_size, self.head_width * count)
        self.normalize = QNormalization() if config.q_normalization else nn.Identity()
        self._init_weights()

    def _init_weights(self):
        """Xavier weights and zero biases, as in the paper (a Lite0 trunk keeps its own)."""
        lite = {id(part) for module in self.modules() if isinstance(module, EfficientNetLite0)
                for part in module.modules()}
        for module in self.modules():
            if isinstance(module, (nn.Conv2d, nn.Linear)) and id(module) not in lite:
                nn.init.xavier_uniform_(module.weight)
                if module.bias is not None:
                    nn.init.zeros_(module.bias)

    def forward(self, crops: torch.Tensor, object_index: torch.Tensor) -> torch.Tensor:
        """
        Quaternions (N, 4), wxyz, for crops (N, 3, S, S) of objects ``object_index`` (N,).

        With several hypotheses, the best-scored one of each crop.
        """
        raw = self._heads(crops, object_index)
        count = self.config.hypotheses
        if count == 1:
            return self.normalize(raw)
        # Hypothesis h is columns 4h..4h+3: picked by a gather, which exports to fewer
        # kernels than reshaping to (N, H, 4).
        best = raw[:, 4 * count:].argmax(dim=1, keepdim=True)
        return self.normalize(raw.gather(1, best * 4 + torch.arange(4, device=raw.device)))

    def hypotheses(self, crops: torch.Tensor,
                   object_index: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """
        All hypotheses: quaternions (N, H, 4) wxyz and their scores (N, H) (logits).

        With one hypothesis the score is 0.
        """
        return self.split_hypotheses(self._heads(crops, object_index))

    def split_hypotheses(self, raw: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """One head's outputs (N, head_width) -> quaternions (N, H, 4) and scores (N, H)."""
        count = self.config.hypotheses
        if count == 1:
            return self.normalize(raw).unsqueeze(1), torch.zeros_like(raw[:, :1])
        quats = self.normalize(raw[:, :4 * count].reshape(-1, count, 4))
        return quats, raw[:, 4 * count:]

    def features(self, crops: torch.Tensor) -> torch.Tensor:
        """(N, fc_size): the hidden FC layer's output the heads read (shared trunk only)."""
        if len(self.trunks) != 1:
            raise ValueError('features() needs the shared trunk (sharing "shared")')
        x = crops if self.config.backbone == 'lite0' else normalize_input(crops)
        return self.trunks[0](x)

    def _heads(self, crops, object_index):
        """Each crop's own head output (N, head_width), before q-normalization."""
        if len(self.trunks) == 1:
            features = self.features(crops)
        else:
            x = crops if self.config.backbone == 'lite0' else normalize_input(crops)
            features = x.new_empty((len(x), self.config.fc_size))
            for k in torch.unique(object_index).tolist():
                chosen = object_index == k
                features[chosen] = self.trunks[k](x[chosen])
        # Columns w k .. w k + w - 1 of all heads' outputs. Offsets from a constant keep an
        # exported graph free of shape computations (and the batch free).
        width = self.head_width
        columns = object_index.unsqueeze(1) * width + torch.arange(width,
                                                                   device=features.device)
        return self.head(features).gather(1, columns)


class HypothesisOutputs(nn.Module):
    """A QNet whose outputs are all its hypotheses (``QNet.hypotheses``), for a runner's graph."""

    def __init__(self, network: QNet) -> None:
        super().__init__()
        self.network = network

    def forward(self, crops: torch.Tensor,
                object_index: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Quaternions (N, H, 4) wxyz and scores (N, H) of (N, 3, S, S) crops."""
        return self.network.hypotheses(crops, object_index)
