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

"""The compact detector: shapes, decoding, box mapping, second stage, detection metrics."""

import numpy as np
import pytest
import torch

from bbpose_ros.core.eval.detection import average_precision, box_errors, score_detections
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.nets.detector import CenterBoxNet, decode, DetectorConfig
from bbpose_ros.core.nets.verifier import CandidateVerifier
from bbpose_ros.core.pipeline.box_detector import best_per_class, BoxDetector
from bbpose_ros.core.pipeline.poses import Detection

OBJECTS = ('ape', 'can', 'cat', 'driller', 'duck', 'eggbox', 'glue', 'holepuncher')
TORCH = PipelineOptions(inference_backend='torch')


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
    np.testing.assert_allclose(boxes[0], expected, atol=1e-4)


class _FixedNet(torch.nn.Module):
    def __init__(self, heat, sides, verifier=None, candidates=4):
        super().__init__()
        self.config = DetectorConfig(OBJECTS, candidates=candidates)
        self.heat, self.sides = heat, sides
        self.verifier = verifier

    def forward(self, images):
        return self.heat[None], self.sides[None]


def test_box_detector_maps_boxes_to_the_full_frame():
    heat, sides = _crafted([(0, 10, 20, 0.9, (16.0, 8.0, 24.0, 8.0)),
                            (1, 5, 5, 0.8, (4.0, 4.0, 4.0, 4.0))])
    detector = BoxDetector(_FixedNet(heat, sides), ['ape', 'cat'], TORCH)
    detections = detector(np.zeros((480, 640, 3), dtype=np.uint8))
    assert [d.object_name for d in detections] == ['ape']      # 'can' is not wanted
    box_in = np.array([163.5 - 16, 83.5 - 8, 163.5 + 24, 83.5 + 8])
    np.testing.assert_allclose(detections[0].box_uv, (box_in + 0.5) * 2 - 0.5)


def test_cascade_forward_shapes():
    config = DetectorConfig(OBJECTS, verifier_channels=(4, 8, 8, 8), verifier_crop_size=32)
    net = CenterBoxNet(config).eval()
    with torch.inference_mode():
        logits, corrections = net.verifier.outputs(torch.rand(5, 3, 32, 32))
        probability, _ = net.verifier(torch.rand(5, 3, 32, 32), torch.arange(5))
    assert logits.shape == (5, 9) and corrections.shape == (5, 4) and probability.shape == (5,)
    assert torch.all((probability > 0) & (probability < 1))
    crops, classes = torch.rand(5, 3, 32, 32), torch.tensor([0, 3, 7, 7, 2])
    with torch.inference_mode():
        probability, _ = net.verifier(crops, classes)
        expected = torch.softmax(net.verifier.outputs(crops)[0], dim=1)[torch.arange(5),
                                                                        classes + 1]
    torch.testing.assert_close(probability, expected)      # column 0 is background
    assert CenterBoxNet(DetectorConfig(OBJECTS)).verifier is None


class _BrightnessVerifier(torch.nn.Module):
    """Second stage that trusts a candidate as much as its crop is bright, widens its box."""

    def forward(self, crops, class_index):
        corrections = torch.tensor([-0.1, 0.0, 0.1, 0.2]).expand(len(crops), 4)
        return crops.mean(dim=(1, 2, 3)), corrections


def test_second_stage_rescoring_picks_the_verified_candidate():
    # Two 'ape' peaks: the heatmap prefers the first, the second stage the second (its crop
    # is white) and moves its sides by the corrections times the crop side (1.2 x 16 px);
    # a 'cat' peak on a black crop is dropped by the second stage's score.
    heat, sides = _crafted([(0, 10, 20, 0.9, (8.0, 8.0, 8.0, 8.0)),
                            (0, 20, 30, 0.5, (8.0, 8.0, 8.0, 8.0)),
                            (2, 5, 5, 0.9, (8.0, 8.0, 8.0, 8.0))])
    image = np.zeros((480, 640, 3), dtype=np.uint8)
    centre = np.array([30 * 8 + 3.5, 20 * 8 + 3.5]) * 2       # second peak, full frame
    image[int(centre[1]) - 40:int(centre[1]) + 40, int(centre[0]) - 40:int(centre[0]) + 40] = 255
    net = _FixedNet(heat, sides, _BrightnessVerifier())
    detections = BoxDetector(net, ['ape', 'cat'], TORCH)(image)
    assert [d.object_name for d in detections] == ['ape']
    assert detections[0].score > 0.9
    box_in = np.array([243.5 - 8, 163.5 - 8, 243.5 + 8, 163.5 + 8])
    box_in += np.array([-0.1, 0.0, 0.1, 0.2]) * 1.2 * 16
    np.testing.assert_allclose(detections[0].box_uv, (box_in + 0.5) * 2 - 0.5, atol=1e-4)


def test_best_per_class_keeps_the_top_scores_above_the_threshold():
    classes = np.array([0, 0, 1, 2, 0])
    scores = np.array([0.5, 0.9, 0.2, 0.4, 0.8])
    boxes = np.arange(20.0).reshape(5, 4)
    kept = best_per_class(classes, scores, boxes, 0.3, 2)
    assert kept[0].tolist() == [0, 0, 2] and kept[1].tolist() == [0.9, 0.8, 0.4]
    np.testing.assert_array_equal(kept[2], boxes[[1, 4, 3]])


def test_verifier_refuses_a_crop_size_off_the_pooling_grid():
    with pytest.raises(ValueError, match='multiple of 8'):
        CandidateVerifier((4, 4, 4, 4), 8, 30)


def test_average_precision():
    assert abs(average_precision([0.9, 0.8, 0.7], [True, False, True], 2) - 5 / 6) < 1e-12
    assert average_precision([0.9], [True], 4) == 0.25
    assert np.isnan(average_precision([], [], 0))


def test_box_errors_tell_a_shrunk_box_by_its_size(lmo_frames):
    frames = lmo_frames[:5]

    def shrunk(box, scale=0.9):
        centre, half = (box[:2] + box[2:]) / 2, (box[2:] - box[:2]) / 2 * scale
        return np.concatenate([centre - half, centre + half])

    detections = [[Detection(i.object_name, 1.0, shrunk(i.box_uv)) for i in frame.instances]
                  for frame in frames]
    report = score_detections(frames, detections, ['ape', 'can', 'cat', 'duck'])
    for figures in report['detection'].values():
        assert figures['recall_iou50'] == 1.0
        assert figures['size_error_median'] == pytest.approx(-0.1)
        assert 0.02 < figures['side_error_rms'] < 0.07
    assert np.isnan(box_errors(np.zeros((0, 4)), np.zeros((0, 4)))['side_error_rms'])
