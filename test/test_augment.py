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


"""Photometric augmentation of training batches: the basic and the strong style."""

import numpy as np
import pytest
import torch

from bbpose_ros.core.training.augment import augment_batch, photometric, strong_photometric


def checkerboards(count=64, size=32):
    """(count, 3, size, size) coloured checkerboards with 4-pixel squares, 0..1."""
    rows, cols = np.mgrid[0:size, 0:size]
    board = ((rows // 4 + cols // 4) % 2).astype(np.float32)
    colors = np.random.default_rng(0).uniform(0.2, 0.8, (count, 3, 2)).astype(np.float32)
    images = colors[..., 0, None, None] + board * (colors[..., 1] - colors[..., 0])[..., None,
                                                                                    None]
    return torch.from_numpy(np.ascontiguousarray(images))


def gradient_energy(images):
    """(N,) mean squared horizontal difference of each image."""
    return ((images[..., 1:] - images[..., :-1]) ** 2).mean(dim=(1, 2, 3))


def test_strong_augmentation_blurs_greys_and_stays_in_range():
    original = checkerboards()
    images = strong_photometric(original.clone(), torch.Generator().manual_seed(3))
    assert images.shape == original.shape and images.dtype == torch.float32
    assert images.min() >= 0.0 and images.max() <= 1.0
    again = strong_photometric(original.clone(), torch.Generator().manual_seed(3))
    torch.testing.assert_close(images, again)          # the generator decides everything
    spread = (images.max(dim=1).values - images.min(dim=1).values).amax(dim=(1, 2))
    assert (spread <= 2 / 255).sum() >= 1              # some images turned grey
    ratio = gradient_energy(images) / gradient_energy(original)
    assert (ratio < 0.5).sum() >= 10                   # blurred (or flattened by contrast)
    # Stronger than the basic style on average.
    basic = photometric(original.clone(), torch.Generator().manual_seed(3))
    assert (images - original).abs().mean() > 1.5 * (basic - original).abs().mean()


def test_augment_batch_dispatches_by_style():
    original = checkerboards(8)
    unchanged = augment_batch(original.clone(), torch.Generator().manual_seed(1), 0.0, 'strong')
    torch.testing.assert_close(unchanged, original)
    basic = augment_batch(original.clone(), torch.Generator().manual_seed(1), 1.0, 'basic')
    torch.testing.assert_close(basic, photometric(original.clone(),
                                                  torch.Generator().manual_seed(1)))
    strong = augment_batch(original.clone(), torch.Generator().manual_seed(1), 1.0, 'strong')
    torch.testing.assert_close(strong, strong_photometric(original.clone(),
                                                          torch.Generator().manual_seed(1)))
    with pytest.raises(ValueError, match='augmentation style'):
        augment_batch(original, torch.Generator(), 1.0, 'wild')
