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
The shipped weights on a few real LM-O frames: a documented accuracy floor.

The floors sit well below what the shipped files measured on all 100 frames (see the numbers
in the comments), so the test catches a broken or swapped weight file, not noise.
"""

import numpy as np
import pytest

from bbpose_ros.core.eval.detection import evaluate_detections
from bbpose_ros.core.eval.evaluation import evaluate
from bbpose_ros.core.pipeline.estimators import load_pipeline
from bbpose_ros.core.pipeline.hypotheses import DEFAULT_BOX_CONSISTENCY_WEIGHT
from bbpose_ros.core.pipeline.pose_pipeline import FrameResult

FRAMES = 12

# Measured with the shipped files on the 100 frames: detector (heatmap + second stage)
# recall @ IoU 0.5 (visible fraction >= 0.3) 0.31, mean over objects (duck 0.78, ape 0.43,
# holepuncher 0.30, cat 0.29, others 0.14-0.20); 0.24 on the first 12 frames (the one-stage
# detector before it: 0.25 and 0.18). Q-Net (8, 16, 24, 32), first stride 2,
# trained on upright views with 8 hypotheses, median rotation error with ground-truth boxes,
# mean over objects: 47.1 deg with its best-scored hypotheses (47.9 deg on the first 12
# frames; the one-hypothesis Q-Net before it: 56.9, the Q-Net trained on any roll: 81.4; a
# random guess gives ~126 deg); 40.0 deg with the hypothesis the Bounding Box Equation fits
# best (load_pipeline's default), but 57.9 on the first 12 frames (11 instances an object).
# Raise these floors when better weights ship.
DETECTOR_RECALL_FLOOR = 0.12
ROTATION_MEDIAN_CEILING_DEG = 70.0


@pytest.fixture(scope='module')
def pipeline(lmo_models):
    return load_pipeline(lmo_models, threads=2)


def test_hypotheses_are_chosen_by_the_box_unless_the_weight_is_zero(pipeline, lmo_models):
    assert pipeline.rotation_estimator.all_hypotheses
    assert pipeline.hypothesis_selector.weight == DEFAULT_BOX_CONSISTENCY_WEIGHT
    plain = load_pipeline(lmo_models, threads=2, box_consistency_weight=0.0)
    assert not plain.rotation_estimator.all_hypotheses


def test_pipeline_runs_on_a_real_frame(pipeline, lmo_frames):
    frame = lmo_frames[0]
    result = pipeline.estimate(frame.load_image(), frame.camera)
    assert isinstance(result, FrameResult)
    for pose in result.poses:
        assert pose.rotation.shape == (3, 3) and np.all(np.isfinite(pose.translation))
        np.testing.assert_allclose(pose.rotation @ pose.rotation.T, np.eye(3), atol=1e-6)


def test_detector_recall_floor(pipeline, lmo_frames):
    report = evaluate_detections(lmo_frames[:FRAMES], pipeline, progress=False)
    assert report['mean']['recall_iou50_visib30'] >= DETECTOR_RECALL_FLOOR


def test_rotation_error_floor_with_ground_truth_boxes(pipeline, lmo_frames):
    report = evaluate(lmo_frames[:FRAMES], pipeline, boxes='gt', rotation='estimator',
                      progress=False)
    assert report['mean']['re_median_deg'] <= ROTATION_MEDIAN_CEILING_DEG
