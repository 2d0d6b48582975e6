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

"""Choosing among rotation hypotheses by the Bounding Box Equation's misfit, on real boxes."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bbpose_ros.core.geometry.rotations import rotation_error_deg
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.pipeline.hypotheses import box_misfit, farthest_points, HypothesisSelector
from bbpose_ros.core.pipeline.pose_pipeline import PosePipeline
from bbpose_ros.core.pipeline.poses import Detection, RotationHypotheses
from bbpose_ros.core.util.errors import InputError

SHIPPED = PipelineOptions()

# Decoys: the true rotation turned 90 deg about the model's x, y or z axis, or 180 about x.
DECOY_TURNS = Rotation.from_rotvec(np.pi / 2 * np.eye(3)).as_matrix()
DECOY_TURNS = np.concatenate([DECOY_TURNS, Rotation.from_rotvec([[np.pi, 0, 0]]).as_matrix()])


def real_hypotheses(frames, models):
    """(frame, detections, RotationHypotheses): truth first, then decoys, equally likely."""
    for frame in frames:
        instances = [i for i in frame.instances if i.visib_fract >= 0.1
                     and not models[i.object_name].is_symmetric]
        if not instances:
            continue
        truth = np.stack([i.rotation for i in instances])
        rotations = np.concatenate([truth[:, None], truth[:, None] @ DECOY_TURNS], axis=1)
        log_probs = np.full(rotations.shape[:2], -np.log(rotations.shape[1]))
        detections = [Detection(i.object_name, 1.0, i.box_uv) for i in instances]
        yield frame, detections, RotationHypotheses(rotations, log_probs)


def test_the_box_picks_out_the_true_rotation_among_turned_ones(lmo_frames, lmo_models):
    selector = HypothesisSelector(lmo_models, SHIPPED)
    right = []
    for frame, detections, hypotheses in real_hypotheses(lmo_frames, lmo_models):
        chosen = selector(frame.camera, detections, hypotheses)
        # Decoys are 90 deg or more away; equal matrices read ~1e-6 deg off the trace.
        right.extend(rotation_error_deg(chosen, hypotheses.rotations[:, 0]) < 1e-3)
    assert len(right) > 100
    assert np.mean(right) > 0.8


def test_zero_weight_keeps_the_likeliest_hypothesis(lmo_frames, lmo_models):
    frame, detections, hypotheses = next(real_hypotheses(lmo_frames, lmo_models))
    log_probs = hypotheses.log_probs.copy()
    log_probs[:, 2] += 1.0                    # a decoy is the network's favourite
    favoured = RotationHypotheses(hypotheses.rotations, log_probs)
    selector = HypothesisSelector(lmo_models, PipelineOptions(box_consistency_weight=0.0))
    chosen = selector(frame.camera, detections, favoured)
    np.testing.assert_array_equal(chosen, hypotheses.rotations[:, 2])


def test_pipeline_chooses_a_hypothesis_before_the_translation(lmo_frames, lmo_models):
    frame, detections, hypotheses = next(real_hypotheses(lmo_frames, lmo_models))
    pipeline = PosePipeline(lmo_models, PipelineOptions(refine=False),
                            rotation_estimator=lambda *args: hypotheses)
    result = pipeline.estimate(frame.load_image(), frame.camera, detections)
    assert 'hypothesis_selection' in result.timings_ms
    chosen = np.stack([pose.rotation for pose in result.poses])
    selector = HypothesisSelector(lmo_models, SHIPPED)
    np.testing.assert_array_equal(chosen, selector(frame.camera, detections, hypotheses))


def test_box_misfit_is_the_largest_residual_over_the_longest_side():
    residuals = np.array([[1.0, -4.0, 2.0, 0.5], [0.0, 0.0, 0.0, 0.0]])
    boxes = np.array([[10.0, 20.0, 50.0, 100.0], [0.0, 0.0, 30.0, 10.0]])
    np.testing.assert_allclose(box_misfit(residuals, boxes), [4.0 / 80.0, 0.0])


def test_farthest_points_spread_over_the_set(lmo_models):
    hull = lmo_models['driller'].hull_points
    chosen = farthest_points(hull, 64)
    assert len(np.unique(chosen, axis=0)) == 64
    # Every hull point lies near a chosen one: within a small share of the object's size.
    gaps = np.linalg.norm(hull[:, None] - chosen[None], axis=2).min(axis=1)
    assert gaps.max() < 0.2 * lmo_models['driller'].diameter
    np.testing.assert_array_equal(farthest_points(hull[:10], 64), hull[:10])


@pytest.mark.parametrize('weight', [-1.0, float('nan')])
def test_bad_weight_is_refused(weight):
    with pytest.raises(InputError, match='box_consistency_weight: .* out of range'):
        PipelineOptions(box_consistency_weight=weight)


def test_hypotheses_must_match_the_detections(lmo_frames, lmo_models):
    frame, detections, hypotheses = next(real_hypotheses(lmo_frames, lmo_models))
    with pytest.raises(InputError, match=f'for {len(detections) - 1} detections'):
        HypothesisSelector(lmo_models, SHIPPED)(
            frame.camera, detections[1:], hypotheses)
