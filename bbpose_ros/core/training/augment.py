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

import numpy as np
import torch

from bbpose_ros.core.synth.effects import adjust_colors, jpeg_roundtrip
from bbpose_ros.core.training.settings import AUGMENT_STYLES

IMAGE_AXES, CHANNEL_AXIS = (1, 2, 3), 1      # of an (N, 3, H, W) batch


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
    adjust_colors(images, IMAGE_AXES, CHANNEL_AXIS, contrast=contrast, gains=gains,
                  brightness=brightness)
    sigma = torch.rand((n, 1, 1, 1), generator=generator) * 0.03 * strength
    images.add_(torch.randn(images.shape, generator=generator) * sigma)
    return images.clamp_(0.0, 1.0)


def augment_batch(images: torch.Tensor, generator: torch.Generator, strength: float,
                  style: str = 'basic') -> torch.Tensor:
    """
    Augment a float batch (N, 3, H, W) in 0..1 with ``photometric`` or ``strong_photometric``.

    ``style`` is one of AUGMENT_STYLES; ``strength`` 0 leaves the images as they are.
    """
    if style not in AUGMENT_STYLES:
        raise ValueError(f'augmentation style must be one of {AUGMENT_STYLES}, got {style!r}')
    if strength <= 0:
        return images
    if style == 'strong':
        return strong_photometric(images, generator, strength)
    return photometric(images, generator, strength)


def strong_photometric(images: torch.Tensor, generator: torch.Generator,
                       strength: float = 1.0) -> torch.Tensor:
    """
    Strong photometric augmentation in the manner of CosyPose and GDR-Net.

    Each image gets, each with its own probability: Gaussian blur (sigma up to 2 px) or
    sharpening, colour saturation (x0-2), contrast (x0.5-1.5), brightness (+-0.25), per
    channel gains (x0.8-1.2), Gaussian sensor noise (sigma up to 0.06), grey, JPEG
    compression (quality 20-90), in that order. ``strength`` scales the probabilities
    (capped at 1) and the sizes of the continuous perturbations.

    Args:
        images: (N, 3, H, W) float RGB in 0..1 (changed in place and returned).
        generator: torch.Generator of the draws.
        strength: > 0.

    """
    n = len(images)

    def chosen(probability):
        return torch.rand(n, generator=generator) < min(probability * strength, 1.0)

    def uniform(low, high):
        mid, half = (low + high) / 2, (high - low) / 2 * strength
        return mid + (torch.rand(n, generator=generator) * 2 - 1) * half

    blur, sharpen = chosen(0.4), chosen(0.3)
    sigmas, amounts = uniform(0.3, 2.0).clamp(min=0.1), uniform(0.0, 1.5).clamp(min=0.0)
    for k in range(n):
        if blur[k]:
            images[k] = _gaussian_blur(images[k], float(sigmas[k]))
        elif sharpen[k]:
            smooth = _gaussian_blur(images[k], 1.0)
            images[k] += float(amounts[k]) * (images[k] - smooth)
    saturation = torch.where(chosen(0.5), uniform(0.0, 2.0).clamp(min=0.0), torch.ones(n))
    contrast = torch.where(chosen(0.5), uniform(0.5, 1.5), torch.ones(n))
    brightness = torch.where(chosen(0.5), uniform(-0.25, 0.25), torch.zeros(n))
    gains = 1 + (torch.rand((n, 3, 1, 1), generator=generator) * 2 - 1) * 0.2 * strength
    adjust_colors(images, IMAGE_AXES, CHANNEL_AXIS, saturation=saturation.view(n, 1, 1, 1),
                  contrast=contrast.view(n, 1, 1, 1), gains=gains,
                  brightness=brightness.view(n, 1, 1, 1))
    noisy = chosen(0.5).view(n, 1, 1, 1)
    sigma = torch.rand((n, 1, 1, 1), generator=generator) * 0.06 * strength * noisy
    images.add_(torch.randn(images.shape, generator=generator) * sigma)
    images.copy_(torch.where(chosen(0.1).view(n, 1, 1, 1), images.mean(dim=1, keepdim=True),
                             images))
    images.clamp_(0.0, 1.0)
    jpeg, qualities = chosen(0.3), uniform(20, 90).clamp(5, 100)
    for k in range(n):
        if jpeg[k]:
            images[k] = _jpeg(images[k], int(qualities[k]))
    return images


def _gaussian_blur(image, sigma):
    """Blur a (3, H, W) float image with a separable Gaussian of ``sigma`` pixels."""
    radius = max(1, int(3 * sigma + 0.5))
    x = torch.arange(-radius, radius + 1, dtype=image.dtype)
    kernel = torch.exp(-x ** 2 / (2 * sigma ** 2))
    kernel /= kernel.sum()
    padded = torch.nn.functional.pad(image[None], (radius, radius, radius, radius),
                                     mode='replicate')
    rows = torch.nn.functional.conv2d(padded, kernel.view(1, 1, 1, -1).expand(3, 1, 1, -1),
                                      groups=3)
    return torch.nn.functional.conv2d(rows, kernel.view(1, 1, -1, 1).expand(3, 1, -1, 1),
                                      groups=3)[0]


def _jpeg(image, quality):
    """Encode a (3, H, W) float RGB image as JPEG at ``quality`` and decode it (0..1)."""
    pixels = (image.permute(1, 2, 0).contiguous().numpy() * 255 + 0.5).astype(np.uint8)
    return torch.from_numpy(jpeg_roundtrip(pixels, quality)).permute(2, 0, 1).to(
        image.dtype) / 255.0
