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

"""Online augmentation of uint8 training images and of 2D boxes."""

import numpy as np
import torch


def photometric(images, generator, strength=1.0):
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


def jitter_boxes(boxes_uv, rng, side_sigma):
    """
    Move each side of (N, 4) boxes by N(0, side_sigma) times the box's width or height.

    This models a detector's amodal box errors: independent side errors give both centre
    shifts and size errors. Returns (N, 4) boxes, never narrower than 2 px.
    """
    boxes = np.asarray(boxes_uv, dtype=float)
    size = np.concatenate([boxes[:, 2:] - boxes[:, :2]] * 2, axis=1)
    jittered = boxes + rng.normal(0.0, 1.0, boxes.shape) * side_sigma * size
    centre = (jittered[:, :2] + jittered[:, 2:]) / 2
    half = np.maximum((jittered[:, 2:] - jittered[:, :2]) / 2, 1.0)
    return np.concatenate([centre - half, centre + half], axis=1)
