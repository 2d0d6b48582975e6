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

"""Camera effects on synthetic images: colour jitter, blur, sensor noise, JPEG artefacts."""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

if TYPE_CHECKING:
    import torch

    from bbpose_ros.core.synth.config import SynthConfig

    Factor = float | np.ndarray | torch.Tensor


def adjust_colors(images: np.ndarray | torch.Tensor, image_axes: tuple[int, ...],
                  channel_axis: int, saturation: Factor | None = None,
                  contrast: Factor | None = None, gains: Factor | None = None,
                  brightness: Factor | None = None) -> np.ndarray | torch.Tensor:
    """
    Scale the saturation and contrast of float images, gain their channels, add brightness.

    In that order, each step left out where its factor is None: the colours are pulled
    towards (factor < 1) or pushed from each pixel's grey (the mean of its channels), the
    intensities towards or from the image's mean, each channel is multiplied by its gain and
    the brightness added. The synthetic images' colour jitter and the training batches'
    photometric augmentation both do it here.

    Args:
        images: float numpy array or torch tensor (changed in place and returned), e.g.
            one (H, W, 3) image or an (N, 3, H, W) batch.
        image_axes: the axes of one image, over which the contrast's mean is taken, e.g.
            (0, 1, 2) or (1, 2, 3).
        channel_axis: the colour channels' axis, e.g. 2 or 1.
        saturation: factor of the colours' distance from grey.
        contrast: factor of the intensities' distance from the image's mean.
        gains: factor of each channel.
        brightness: added to every intensity.

    The factors are scalars or arrays that broadcast against ``images`` (per image, per
    channel).

    """
    if saturation is not None:
        gray = images.mean(axis=channel_axis, keepdims=True)
        images -= gray
        images *= saturation
        images += gray
    if contrast is not None:
        mean = images.mean(axis=image_axes, keepdims=True)
        images -= mean
        images *= contrast
        images += mean
    if gains is not None:
        images *= gains
    if brightness is not None:
        images += brightness
    return images


def jitter_colors(rng: np.random.Generator, image: np.ndarray,
                  config: SynthConfig) -> np.ndarray:
    """Random brightness, contrast and saturation of an (H, W, 3) uint8 RGB image."""
    saturation = rng.uniform(*config.saturation_range)
    contrast = rng.uniform(*config.contrast_range)
    brightness = rng.uniform(*config.brightness_range)
    image = adjust_colors(image.astype(np.float32), (0, 1, 2), 2, saturation=saturation,
                          contrast=contrast, brightness=brightness)
    return np.clip(image, 0, 255).astype(np.uint8)


def add_noise(rng: np.random.Generator, image: np.ndarray, sigma: float) -> np.ndarray:
    """Add Gaussian noise of ``sigma`` (in 0..255 units) to an (H, W, 3) uint8 image."""
    noise = rng.normal(0.0, sigma, image.shape).astype(np.float32)
    return np.clip(image.astype(np.float32) + noise, 0, 255).astype(np.uint8)


def jpeg_roundtrip(image: np.ndarray, quality: int) -> np.ndarray:
    """Encode an (H, W, 3) uint8 RGB image as JPEG at ``quality`` (0-100) and decode it."""
    bgr = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    ok, data = cv2.imencode('.jpg', bgr, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError('OpenCV failed to encode a JPEG image')
    return cv2.cvtColor(cv2.imdecode(data, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def apply_camera_effects(rng: np.random.Generator, image: np.ndarray,
                         config: SynthConfig) -> np.ndarray:
    """Apply the camera effects of a ``SynthConfig`` to an (H, W, 3) uint8 RGB image."""
    image = jitter_colors(rng, image, config)
    if rng.random() < config.blur_probability:
        image = cv2.GaussianBlur(image, (0, 0), rng.uniform(*config.blur_sigma_range))
    image = add_noise(rng, image, rng.uniform(*config.noise_sigma_range))
    if rng.random() < config.jpeg_probability:
        image = jpeg_roundtrip(image, rng.integers(config.jpeg_quality_range[0],
                                                   config.jpeg_quality_range[1] + 1))
    return image


def color_response(rng: np.random.Generator, image: np.ndarray,
                   white_balance_range: tuple[float, float],
                   gamma_range: tuple[float, float]) -> np.ndarray:
    """
    Apply a camera's colour response to an (H, W, 3) uint8 RGB image: white balance, gamma.

    Each channel is scaled by a gain drawn from ``white_balance_range`` (a colour cast), then
    the 0..1 intensities are raised to a gamma drawn from ``gamma_range`` (> 1 darkens the
    mid-tones, < 1 lifts them; the extremes stay).
    """
    gains = rng.uniform(*white_balance_range, 3).astype(np.float32)
    gamma = float(rng.uniform(*gamma_range))
    lut = np.clip((np.arange(256, dtype=np.float32)[:, None] / 255.0 * gains), 0.0, 1.0)
    lut = np.round(255.0 * lut ** gamma).astype(np.uint8)
    return np.stack([lut[image[..., c], c] for c in range(3)], axis=-1)
