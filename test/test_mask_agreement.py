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

"""Silhouettes against predicted masks: the mask term of the hypothesis ranking."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.nets.crops import square_boxes
from bbpose_ros.core.pipeline.hypotheses import HypothesisSelector
from bbpose_ros.core.pipeline.loader import load_pipeline
from bbpose_ros.core.pipeline.mask_agreement import MaskAgreement
from bbpose_ros.core.pipeline.poses import Detection, RotationHypotheses
from bbpose_ros.core.refine.foreground_masks import ForegroundMasks
from bbpose_ros.core.refine.viewpoint_cache import load_viewpoint_models
from bbpose_ros.core.render.reference import render_silhouette
from bbpose_ros.core.util.errors import InputError

SIZE = 32          # the dense net's mask grid
CONTEXT = 1.25     # square side over the box's longer side


@pytest.fixture(scope='module')
def agreement(lmo_models):
    """Score against masks with the cached viewpoint models of the 8 LM-O objects."""
    return MaskAgreement(load_viewpoint_models(lmo_models, progress=False))


def instances_with_masks(frames, models, count=40):
    """(frame, instance, square, (SIZE, SIZE) exact silhouette of its true pose) tuples."""
    found = []
    for frame in frames[::7]:
        for instance in frame.instances:
            if instance.visib_fract < 0.3:
                continue
            square = square_boxes(instance.box_uv[None], CONTEXT)[0]
            model = models[instance.object_name]
            mask = render_silhouette(frame.camera.cropped(square, SIZE), model.vertices,
                                     model.faces, instance.rotation, instance.translation)
            found.append((frame, instance, square, mask.astype(np.float32)))
            if len(found) == count:
                return found
    return found


def soft_iou(a, b):
    return np.minimum(a, b).sum() / np.maximum(a, b).sum()


def test_contour_silhouette_matches_the_rasterised_mesh(lmo_frames, lmo_models, agreement):
    ious = []
    for frame, instance, square, mask in instances_with_masks(lmo_frames, lmo_models):
        drawn = agreement.silhouettes(frame.camera, instance.object_name,
                                      instance.rotation[None], instance.translation[None],
                                      square[None], SIZE)[0]
        ious.append(soft_iou(drawn, mask))
    # The nearest stored view differs from the pose's by a few degrees; a cell is ~4 px.
    assert np.median(ious) > 0.85
    assert min(ious) > 0.6


def test_the_true_pose_agrees_best_with_its_own_mask(lmo_frames, lmo_models, agreement):
    turns = Rotation.from_rotvec(np.radians(30) * np.eye(3)).as_matrix()
    better = []
    for frame, instance, square, mask in instances_with_masks(lmo_frames, lmo_models):
        rotations = np.concatenate([instance.rotation[None], instance.rotation @ turns])
        scores = agreement(frame.camera, [instance.object_name] * 4, rotations,
                           np.repeat(instance.translation[None], 4, axis=0),
                           ForegroundMasks(np.repeat(mask[None], 4, axis=0),
                                           np.repeat(square[None], 4, axis=0)))
        assert np.all((scores >= 0) & (scores <= 1))
        better.extend(scores[0] > scores[1:])
    assert np.mean(better) > 0.8


def test_the_mask_term_overrules_a_favoured_wrong_hypothesis(lmo_frames, lmo_models,
                                                             agreement):
    cases = [c for c in instances_with_masks(lmo_frames, lmo_models)
             if not lmo_models[c[1].object_name].is_symmetric]
    turn = Rotation.from_rotvec([0.0, np.pi / 2, 0.0]).as_matrix()
    picked_truth = {0.0: [], 20.0: []}
    for frame, instance, square, mask in cases:
        rotations = np.stack([instance.rotation, instance.rotation @ turn])[None]
        hypotheses = RotationHypotheses(rotations, np.log([[0.3, 0.7]]))  # decoy favoured
        detections = [Detection(instance.object_name, 1.0, instance.box_uv)]
        masks = ForegroundMasks(mask[None], square[None])
        for weight in picked_truth:
            selector = HypothesisSelector(lmo_models, PipelineOptions(
                box_consistency_weight=0.0, mask_consistency_weight=weight), agreement)
            chosen = selector.ranked(frame.camera, detections, hypotheses, 1, masks)[0, 0]
            picked_truth[weight].append(np.allclose(chosen, instance.rotation))
    assert len(cases) > 20
    assert not any(picked_truth[0.0])
    assert np.mean(picked_truth[20.0]) > 0.8


def test_bad_mask_settings_are_refused(agreement, lmo_frames):
    with pytest.raises(InputError, match='mask_consistency_weight'):
        PipelineOptions(mask_consistency_weight=-1.0)
    frame = lmo_frames[0]
    instance = frame.instances[0]
    with pytest.raises(InputError, match='1 names, 1 rotations, 1 translations and 2 masks'):
        agreement(frame.camera, [instance.object_name], instance.rotation[None],
                  instance.translation[None],
                  ForegroundMasks(np.zeros((2, SIZE, SIZE)), np.zeros((2, 4))))


def test_a_mask_weight_runs_the_dense_net():
    assert PipelineOptions(mask_consistency_weight=10.0).runs_dense()
    assert not PipelineOptions(mask_consistency_weight=10.0, pose_source='dense').ranks_by_mask
    assert not PipelineOptions().ranks_by_mask


def test_the_pipeline_ranks_by_the_dense_nets_masks(lmo_frames, lmo_models):
    pipeline = load_pipeline(lmo_models, PipelineOptions(mask_consistency_weight=20.0,
                                                         refine=False, inference_threads=1))
    assert pipeline.hypothesis_selector.agreement is not None
    frame = lmo_frames[0]
    result = pipeline.estimate(frame.load_image(), frame.camera)
    assert result.poses
    assert {'correspondences', 'hypothesis_selection'} <= set(result.timings_ms)
