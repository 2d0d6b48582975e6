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
The dense correspondence net: per cell of a crop, where on the model it lies, and masks.

A network of its own beside Q-Net (Q-Net and its Dot Product Loss stay as they are): the
ImageNet EfficientNet-Lite0 trunk to stride 16 (blocks 0-10, as Q-Net's), a light
top-down decoder (CDPN and GDR-Net decode their trunks the same way, with more width):
1x1 laterals of the stride-16, -8 and -4 features to ``channels``, nearest upsampling and
sums, a 3x3 convolution at stride 4, then upsampled to stride 2, plus a lateral of the
stride-2 features, a 3x3 convolution at ``channels / 2`` and a 1x1 output. Output map side
M = crop_size / 2 (32 for a 64 px crop). Per object class five channels: the model
coordinates normalised by the model's axis-aligned box (``synth.dense_targets``; 3
channels, unbounded, about [0, 1]), the visible-mask logit and the amodal-mask logit; the
detection's class selects its five.

Crops are cut as Q-Net's (square, ``context`` times the box's longest side), so one crop
can feed both networks.
"""

from dataclasses import dataclass

import torch
from torch import nn
import torch.nn.functional as F

from bbpose_ros.core.nets.config_dict import ConfigDict
from bbpose_ros.core.nets.efficientnet_lite import BLOCK_CHANNELS, BLOCK_STRIDES, \
    EfficientNetLite0

# Trunk taps (block indices) at strides 2, 4, 8 and 16.
TAPS = (0, 2, 4, 10)
OUTPUT_STRIDE = 2
# Output channels per object: x, y, z (normalised), visible logit, amodal logit.
PER_OBJECT = 5


@dataclass(frozen=True)
class DenseConfig(ConfigDict):
    """
    Architecture and convention of a dense net (stored in its weight file).

    Attributes:
        objects: object names, five output channels each, in this order.
        crop_size: side of the square input crop in pixels (a multiple of 16).
        context: crop side / longest box side.
        channels: decoder width at stride 4 (half of it at stride 2).

    """

    objects: tuple[str, ...]
    crop_size: int = 64
    context: float = 1.2
    channels: int = 64

    def __post_init__(self) -> None:
        if self.crop_size % BLOCK_STRIDES[TAPS[-1]] or self.crop_size <= 0:
            raise ValueError(f'crop_size {self.crop_size} is not a positive multiple of 16')
        if self.channels < 2 or self.channels % 2:
            raise ValueError(f'channels must be an even number >= 2, not {self.channels}')
        if not self.objects:
            raise ValueError('a dense net needs at least one object')

    @property
    def map_size(self) -> int:
        """Side M of the output maps (cells of ``OUTPUT_STRIDE`` crop pixels)."""
        return self.crop_size // OUTPUT_STRIDE


def _conv_bn(cin, cout, kernel):
    return nn.Sequential(nn.Conv2d(cin, cout, kernel, padding=kernel // 2, bias=False),
                         nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


class DenseNet(nn.Module):
    """
    The dense net for one or several objects.

    ``forward(crops, object_index)``: crops (N, 3, S, S) float RGB in 0..1, object_index (N,)
    long -> (N, 5, M, M): normalised coordinates (3), visible logit, amodal logit of each
    crop's own object, M = S / 2.
    """

    def __init__(self, config: DenseConfig) -> None:
        super().__init__()
        self.config = config
        width, fine = config.channels, config.channels // 2
        self.trunk = EfficientNetLite0(blocks=TAPS[-1] + 1)
        self.laterals = nn.ModuleList(
            [_conv_bn(BLOCK_CHANNELS[TAPS[0]], fine, 1)] +
            [_conv_bn(BLOCK_CHANNELS[tap], width, 1) for tap in TAPS[1:]])
        self.mix4 = _conv_bn(width, width, 3)
        self.reduce = _conv_bn(width, fine, 1)
        self.mix2 = _conv_bn(fine, fine, 3)
        self.output = nn.Conv2d(fine, PER_OBJECT * len(config.objects), 1)
        nn.init.zeros_(self.output.bias)
        with torch.no_grad():
            self.output.bias.view(-1, PER_OBJECT)[:, :3] = 0.5   # the model box's centre

    def forward(self, crops: torch.Tensor, object_index: torch.Tensor) -> torch.Tensor:
        """Compute the maps (N, 5, M, M) of crops (N, 3, S, S) of ``object_index`` (N,)."""
        maps = self.output(self.features(crops))
        # Channels 5 k .. 5 k + 4 of each crop's object k, by a gather (no shape arithmetic
        # in an exported graph; the batch stays free).
        index = object_index.view(-1, 1, 1, 1) * PER_OBJECT + \
            torch.arange(PER_OBJECT, device=maps.device).view(1, -1, 1, 1)
        return maps.gather(1, index.expand(-1, -1, maps.shape[2], maps.shape[3]))

    def features(self, crops: torch.Tensor) -> torch.Tensor:
        """(N, channels / 2, M, M): the decoded features the per-object 1x1 output reads."""
        s2, s4, s8, s16 = self.trunk.forward_features(crops, TAPS)
        x = self.laterals[3](s16)
        x = F.interpolate(x, scale_factor=2.0, mode='nearest') + self.laterals[2](s8)
        x = F.interpolate(x, scale_factor=2.0, mode='nearest') + self.laterals[1](s4)
        x = self.reduce(self.mix4(x))
        x = F.interpolate(x, scale_factor=2.0, mode='nearest') + self.laterals[0](s2)
        return self.mix2(x)
