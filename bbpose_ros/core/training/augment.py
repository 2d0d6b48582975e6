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

"""Online photometric augmentation of training image batches."""

import torch


def photometric(images: torch.Tensor, generator: torch.Generator,
                strength: float = 1.0) -> torch.Tensor:
    """
    Random per-image brightness, contrast, colour gains and noise on a float batch.

    Args:
        images: (N, 3, H, W) float RGB in 0..1 (changed in place and returned).
        generator: torch.Generator of the draws.
        strength: scale of every perturbation (0 disables).

    """
    n = len(images)

    def uniform(shape, half_width):
        return (torch.rand(shape, generator=generator) * 2 - 1) * half_width * strength

    gains = 1 + uniform((n, 3, 1, 1), 0.15)
    contrast = 1 + uniform((n, 1, 1, 1), 0.3)
    brightness = uniform((n, 1, 1, 1), 0.12)
    mean = images.mean(dim=(1, 2, 3), keepdim=True)
    images.sub_(mean).mul_(contrast).add_(mean).mul_(gains).add_(brightness)
    sigma = torch.rand((n, 1, 1, 1), generator=generator) * 0.03 * strength
    images.add_(torch.randn(images.shape, generator=generator) * sigma)
    return images.clamp_(0.0, 1.0)
