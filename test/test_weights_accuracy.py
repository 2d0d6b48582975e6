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

The floors sit well below what the shipped files measure, so the test catches a broken or
swapped weight file, not noise.
"""

import numpy as np
import pytest

from bbpose_ros.core.eval.detection import score_detections
from bbpose_ros.core.eval.evaluation import evaluate
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.pipeline.loader import load_pipeline
from bbpose_ros.core.pipeline.poses import FrameResult

FRAMES = 12

# Floors well below what the shipped files measure on these frames and on all 100
# (docs/results.md): a broken, untrained or swapped weight file falls under them, noise does
# not. Raise them when better weights ship.
DETECTOR_RECALL_FLOOR = 0.25
ROTATION_MEDIAN_CEILING_DEG = 60.0


@pytest.fixture(scope='module')
def pipeline(lmo_models):
    return load_pipeline(lmo_models, PipelineOptions(refine=False, inference_threads=2))


def test_hypotheses_are_chosen_by_the_box_unless_the_weight_is_zero(pipeline, lmo_models):
    assert pipeline.rotation_estimator.all_hypotheses
    assert pipeline.hypothesis_selector.options is pipeline.options
    plain = load_pipeline(lmo_models, PipelineOptions(refine=False, inference_threads=2,
                                                      box_consistency_weight=0.0))
    assert not plain.rotation_estimator.all_hypotheses


def test_pipeline_runs_on_a_real_frame(pipeline, lmo_frames):
    frame = lmo_frames[0]
    result = pipeline.estimate(frame.load_image(), frame.camera)
    assert isinstance(result, FrameResult)
    for pose in result.poses:
        assert pose.rotation.shape == (3, 3) and np.all(np.isfinite(pose.translation))
        np.testing.assert_allclose(pose.rotation @ pose.rotation.T, np.eye(3), atol=1e-6)


def test_detector_recall_floor(pipeline, lmo_frames):
    frames = lmo_frames[:FRAMES]
    detections = [pipeline.detector(frame.load_image()) for frame in frames]
    report = score_detections(frames, detections, list(pipeline.models))
    assert report['mean']['recall_iou50_visib30'] >= DETECTOR_RECALL_FLOOR


def test_rotation_error_floor_with_ground_truth_boxes(pipeline, lmo_frames):
    report = evaluate(lmo_frames[:FRAMES], pipeline, boxes='gt', rotation='estimator',
                      progress=False)
    assert report['mean']['re_median_deg'] <= ROTATION_MEDIAN_CEILING_DEG


@pytest.mark.slow   # the dense net on real frames, ~5 s
def test_the_shipped_dense_net_gives_candidates_and_masks(lmo_models, lmo_frames):
    options = PipelineOptions(inference_threads=2, pose_source='dense+qnet', dense_mask='amodal')
    pipeline = load_pipeline(lmo_models, options)
    frame = lmo_frames[0]
    result = pipeline.estimate(frame.load_image(), frame.camera)
    assert result.poses and 'correspondences' in result.timings_ms
    assert {p.source for p in result.poses} <= {'pnp', 'pnp_rotation', 'qnet'}
    maps = pipeline.correspondences.maps(frame.load_image(), [p.detection for p in result.poses])
    # The predicted masks cover part of each crop, not all or nothing.
    assert 0.02 < float(maps.amodal.mean()) < 0.9
