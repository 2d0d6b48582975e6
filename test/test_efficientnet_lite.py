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


"""EfficientNet-Lite0: the module reproduces the ImageNet network of the pretrained wheel."""

import cv2
from matplotlib import cbook
import numpy as np
import pytest
import torch

from bbpose_ros.core.nets.efficientnet_lite import (BLOCK_CHANNELS, BLOCK_STRIDES,
                                                    EfficientNetLite0, SameConv2d)

MILITARY_UNIFORM = 652      # ImageNet class index


def _centre_square(image_rgb, size=224):
    height, width = image_rgb.shape[:2]
    side = min(height, width)
    top, left = (height - side) // 2, (width - side) // 2
    square = cv2.resize(image_rgb[top:top + side, left:left + side], (size, size),
                        interpolation=cv2.INTER_AREA)
    return torch.from_numpy(square).permute(2, 0, 1)[None].float() / 255.0


@pytest.fixture(scope='module')
def classifier():
    return EfficientNetLite0(classifier=True).load_imagenet().eval()


def test_the_pretrained_classifier_recognises_a_photo(classifier):
    """Matplotlib's Grace Hopper portrait is a military uniform, as for other ImageNet nets."""
    path = cbook.get_sample_data('grace_hopper.jpg', asfileobj=False)
    image = cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)
    with torch.no_grad():
        probabilities = classifier(_centre_square(image)).softmax(dim=1)[0]
        assert int(probabilities.argmax()) == MILITARY_UNIFORM
        assert float(probabilities[MILITARY_UNIFORM]) > 0.2
        for variant, size in ((image[:, ::-1], 224), (image, 256)):
            logits = classifier(_centre_square(np.ascontiguousarray(variant), size))
            assert MILITARY_UNIFORM in logits[0].topk(3).indices.tolist()
        noise = torch.rand(1, 3, 224, 224, generator=torch.Generator().manual_seed(0))
        assert float(classifier(noise).softmax(dim=1)[0].max()) < 0.2


def test_a_cut_trunk_gives_the_full_networks_features(classifier):
    trunk = EfficientNetLite0(blocks=11).load_imagenet().eval()
    images = torch.rand(2, 3, 120, 160, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        mine = trunk.forward_features(images, (4, 10))
        full = classifier.forward_features(images, (4, 10))
    for index, ours, theirs in zip((4, 10), mine, full):
        stride = BLOCK_STRIDES[index]
        assert ours.shape == (2, BLOCK_CHANNELS[index], -(-120 // stride), -(-160 // stride))
        assert torch.equal(ours, theirs)
    assert len(trunk.state_dict()) < len(classifier.state_dict())


def test_same_padding_follows_tensorflow():
    """Stride 2 on an even size pads one pixel on the right/bottom only."""
    conv = SameConv2d(1, 1, 3, stride=2)
    with torch.no_grad():
        conv.weight.zero_()
        conv.weight[0, 0, 2, 2] = 1.0           # picks the bottom-right tap
    image = torch.arange(16.0).reshape(1, 1, 4, 4)
    out = conv(image)
    assert out.shape == (1, 1, 2, 2)
    assert out[0, 0].tolist() == [[10.0, 0.0], [0.0, 0.0]]     # symmetric: 5, 7, 13, 15
