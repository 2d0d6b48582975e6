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
The networks' input from uint8 images, one conversion for training and inference.

Both networks take (N, 3, H, W) float RGB in 0..1. Training converts its uint8 batches with
``images_to_input`` before augmenting them; at inference ``ImageInput`` puts the same
conversion inside the network, so a runner is fed the (N, H, W, 3) uint8 crops or frame as
they are and an exported ONNX graph does the conversion in its own kernels.
"""

from typing import Any

import torch
from torch import nn

# The networks trained from scratch centre their 0..1 input on 0.5 and scale it by 1 / 0.25
# (roughly unit variance for natural images), inside the network so exports carry it; an
# ImageNet trunk normalises with ImageNet's statistics instead (``efficientnet_lite``).
INPUT_MEAN = 0.5
INPUT_STD = 0.25


def normalize_input(images: torch.Tensor) -> torch.Tensor:
    """(N, 3, H, W) float RGB in 0..1 -> the centred, scaled input of the first layer."""
    return (images - INPUT_MEAN) / INPUT_STD


def images_to_input(images_nhwc: torch.Tensor) -> torch.Tensor:
    """(N, H, W, 3) uint8 RGB tensor -> (N, 3, H, W) float 0..1 with channels_last strides."""
    return images_nhwc.permute(0, 3, 1, 2).float().div(255.0)


class ImageInput(nn.Module):
    """``network`` fed (N, H, W, 3) uint8 images: ``forward(images, *rest)``."""

    def __init__(self, network: nn.Module) -> None:
        super().__init__()
        self.network = network

    def forward(self, images_nhwc: torch.Tensor, *rest: torch.Tensor) -> Any:
        """Run the wrapped network on uint8 images and its other inputs ``rest``."""
        return self.network(images_to_input(images_nhwc), *rest)
