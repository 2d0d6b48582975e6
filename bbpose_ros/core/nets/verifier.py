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
The detector's second stage: re-scores the heatmap's candidate boxes on small crops.

MTCNN, the paper's detector, is a cascade: a proposal network over the whole image, then
networks that re-score each proposal on a crop of its own. Here the heatmap network
proposes the few highest peaks of every class and this network, fed a square crop of
each candidate's box cut from the same 320x240 network input, says which object (or
background) it shows and, like MTCNN's R-Net, how far each side of the object's amodal box
lies from the candidate's; the candidate's score becomes the probability of its own class
and its box the corrected one. Trained on the heatmap network's candidates in rendered
scenes, background included, it learns the negatives the first stage ranks high.
"""

from collections.abc import Sequence

import torch
from torch import nn

from bbpose_ros.core.nets.images import normalize_input


def _conv(cin, cout):
    return nn.Sequential(nn.Conv2d(cin, cout, 3, padding=1, bias=False),
                         nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


class CandidateVerifier(nn.Module):
    """
    Classifies square crops into background (column 0) or one of ``classes`` objects.

    ``forward(crops, class_index)``: (N, 3, S, S) float RGB in 0..1 and (N,) long class
    indices -> ((N,) probability that each crop shows its candidate's class, (N, 4) side
    corrections). ``outputs(crops)``: ((N, 1 + classes) class scores, (N, 4) side
    corrections), for training. A correction is (true side - candidate side) / crop side
    for the left, top, right and bottom sides of the amodal box.
    """

    def __init__(self, channels: Sequence[int], classes: int, crop_size: int) -> None:
        super().__init__()
        if crop_size % 8:
            raise ValueError(f'verifier crop size must be a multiple of 8, got {crop_size}')
        c1, c2, c3, c4 = channels
        self.features = nn.Sequential(
            _conv(3, c1), nn.MaxPool2d(2), _conv(c1, c2), nn.MaxPool2d(2),
            _conv(c2, c3), nn.MaxPool2d(2), _conv(c3, c4), nn.Flatten())
        self.classify = nn.Sequential(
            nn.Linear(c4 * (crop_size // 8) ** 2, 128), nn.ReLU(inplace=True),
            nn.Linear(128, 1 + classes + 4))

    def outputs(self, crops: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(N, 1 + classes) class scores (column 0: background), (N, 4) side corrections."""
        head = self.classify(self.features(normalize_input(crops)))
        return head[:, :-4], head[:, -4:]

    def forward(self, crops: torch.Tensor,
                class_index: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(N,) probability of each crop's class ``class_index`` (0-based), (N, 4) corrections."""
        logits, corrections = self.outputs(crops)
        probabilities = torch.softmax(logits, dim=1)
        return probabilities.gather(1, (class_index + 1).unsqueeze(1)).squeeze(1), corrections
