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

"""The compact detector: shapes, decoding, box mapping to the frame, detection metrics."""

import numpy as np
import torch

from bbpose_ros.core.detection_eval import average_precision
from bbpose_ros.core.estimators import BoxDetector
from bbpose_ros.core.nets.detector import CenterBoxNet, decode, DetectorConfig

OBJECTS = ('ape', 'can', 'cat', 'driller', 'duck', 'eggbox', 'glue', 'holepuncher')


def test_forward_shapes():
    net = CenterBoxNet(DetectorConfig(OBJECTS)).eval()
    with torch.inference_mode():
        heat, sides = net(torch.rand(2, 3, 240, 320))
    assert heat.shape == (2, 8, 30, 40) and sides.shape == (2, 4, 30, 40)


def _crafted(peaks):
    """Heatmap logits and log sides with peaks [(class, row, col, prob, (l, t, r, b))]."""
    heat = torch.full((8, 30, 40), -10.0)
    sides = torch.zeros(4, 30, 40)
    for cls, row, col, prob, dist in peaks:
        heat[cls, row, col] = float(torch.logit(torch.tensor(prob)))
        sides[:, row, col] = torch.log(torch.tensor(dist) / 8.0)
    return heat, sides


def test_decode_finds_peaks_and_boxes():
    heat, sides = _crafted([(2, 10, 20, 0.9, (16.0, 8.0, 24.0, 8.0)),
                            (5, 3, 4, 0.2, (8.0, 8.0, 8.0, 8.0))])
    classes, scores, boxes = decode(heat, sides, 8, 0.3, 1)
    assert classes.tolist() == [2]
    assert abs(float(scores[0]) - 0.9) < 1e-5
    centre = np.array([20 * 8 + 3.5, 10 * 8 + 3.5])
    expected = [centre[0] - 16, centre[1] - 8, centre[0] + 24, centre[1] + 8]
    np.testing.assert_allclose(boxes[0].numpy(), expected, atol=1e-4)


class _FixedNet(torch.nn.Module):
    def __init__(self, heat, sides):
        super().__init__()
        self.config = DetectorConfig(OBJECTS)
        self.heat, self.sides = heat, sides

    def forward(self, images):
        return self.heat[None], self.sides[None]


def test_box_detector_maps_boxes_to_the_full_frame():
    heat, sides = _crafted([(0, 10, 20, 0.9, (16.0, 8.0, 24.0, 8.0)),
                            (1, 5, 5, 0.8, (4.0, 4.0, 4.0, 4.0))])
    detector = BoxDetector(_FixedNet(heat, sides), ['ape', 'cat'], 0.3, 1, backend='torch')
    detections = detector(np.zeros((480, 640, 3), dtype=np.uint8))
    assert [d.object_name for d in detections] == ['ape']      # 'can' is not wanted
    box_in = np.array([163.5 - 16, 83.5 - 8, 163.5 + 24, 83.5 + 8])
    np.testing.assert_allclose(detections[0].box_uv, (box_in + 0.5) * 2 - 0.5)


def test_average_precision():
    assert abs(average_precision([0.9, 0.8, 0.7], [True, False, True], 2) - 5 / 6) < 1e-12
    assert average_precision([0.9], [True], 4) == 0.25
    assert np.isnan(average_precision([], [], 0))
