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

"""The region-based refiner: viewpoint models, convergence on renders, real LM-O frames."""

import dataclasses

import cv2
import numpy as np
import pytest

from bbpose_ros.core.eval.metrics import cm_deg_errors
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.dense_pnp import DensePose
from bbpose_ros.core.geometry.rotations import exp_so3, perturb_pose, rotation_error_deg
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.nets.crops import square_boxes
from bbpose_ros.core.pipeline.correspondences import DenseMaps
from bbpose_ros.core.pipeline.mask_agreement import MaskAgreement
from bbpose_ros.core.pipeline.pose_pipeline import PosePipeline
from bbpose_ros.core.pipeline.poses import Detection, PoseEstimate
from bbpose_ros.core.pipeline.refinement import PoseRefiner
from bbpose_ros.core.pipeline.tracking import PoseTracker
from bbpose_ros.core.refine import contour_projection
from bbpose_ros.core.refine.color_histograms import color_bins
from bbpose_ros.core.refine.foreground_masks import ForegroundMasks
from bbpose_ros.core.refine.refiner import refine_poses, Refinement, RefinerConfig
from bbpose_ros.core.refine.region_modality import MIN_VARIANCE, RegionModality
from bbpose_ros.core.refine.viewpoint_cache import load_viewpoint_models
from bbpose_ros.core.refine.viewpoint_model import (geodesic_directions, look_at_rotation,
                                                    ViewpointModel)
from bbpose_ros.core.render.reference import render_silhouette
from bbpose_ros.core.util.errors import InputError

pytestmark = pytest.mark.slow   # viewpoint models of every mesh, real frames refined: ~30 s

CAMERA = CameraIntrinsics(572.4114, 573.57043, 325.2611, 242.04899, 640, 480)
NAMES = ('ape', 'driller', 'duck', 'holepuncher')
BLANK = np.zeros((CAMERA.height, CAMERA.width, 3), np.uint8)
SHIPPED = PipelineOptions()


def refine_one(model, image, camera, rotation, translation, config=None):
    """Refine one pose of one object with ``refine_poses``; its Refinement."""
    return refine_poses(color_bins(image), camera, [model], [rotation], [translation], SHIPPED,
                        config or RefinerConfig())[0]


@pytest.fixture(scope='module')
def viewpoint_models(lmo_models, tmp_path_factory):
    """Viewpoint models of a few objects, built into a fresh cache folder."""
    cache = tmp_path_factory.mktemp('viewpoints')
    models = {name: lmo_models[name] for name in NAMES}
    return load_viewpoint_models(models, cache, progress=False), cache


def rendered_scene(model, rotation, translation, seed):
    """Draw the object at a pose: a textured silhouette on a smooth colour field."""
    rng = np.random.default_rng(seed)
    mask = render_silhouette(CAMERA, model.vertices, model.faces, rotation, translation)
    coarse = rng.uniform(0, 255, (6, 8, 3))
    rows = np.linspace(0, 5, CAMERA.height)[:, None]
    cols = np.linspace(0, 7, CAMERA.width)[None, :]
    r0, c0 = np.floor(rows).astype(int), np.floor(cols).astype(int)
    r1, c1 = np.minimum(r0 + 1, 5), np.minimum(c0 + 1, 7)
    fr, fc = (rows - r0)[..., None], (cols - c0)[..., None]
    background = ((1 - fr) * (1 - fc) * coarse[r0, c0] + (1 - fr) * fc * coarse[r0, c1]
                  + fr * (1 - fc) * coarse[r1, c0] + fr * fc * coarse[r1, c1])
    colors = model.vertex_colors[rng.integers(0, len(model.vertex_colors),
                                              (CAMERA.height, CAMERA.width))]
    image = np.where(mask[..., None], colors, background) + rng.normal(0, 4, background.shape)
    return np.clip(image, 0, 255).astype(np.uint8)


def test_geodesic_directions_cover_the_sphere():
    for level, count in ((0, 12), (1, 42), (2, 162)):
        directions = geodesic_directions(level)
        assert directions.shape == (count, 3)
        np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0)
    # Every direction has a stored view within the grid's spacing.
    probes = np.random.default_rng(0).normal(size=(500, 3))
    probes /= np.linalg.norm(probes, axis=1, keepdims=True)
    nearest = np.degrees(np.arccos(np.clip((probes @ geodesic_directions(2).T).max(1), -1, 1)))
    assert nearest.max() < 63.0 / 4


def test_viewpoint_model_lies_on_the_silhouette(viewpoint_models, lmo_models):
    models, _ = viewpoint_models
    vpm = models['driller']
    view = 7
    rotation = look_at_rotation(vpm.view_directions[view])
    translation = np.array([0.0, 0.0, 0.8])
    mask = render_silhouette(CAMERA, lmo_models['driller'].vertices,
                             lmo_models['driller'].faces, rotation, translation)
    uv = CAMERA.project(vpm.points[view] @ rotation.T + translation)
    normals = (vpm.normals[view] @ rotation.T)[:, :2]
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-6)
    # Contour points sit on the boundary: inside 2 px inwards, outside 2 px outwards.
    inner = np.round(uv - 2.0 * normals).astype(int)
    outer = np.round(uv + 2.0 * normals).astype(int)
    assert mask[inner[:, 1], inner[:, 0]].mean() > 0.9
    assert (~mask[outer[:, 1], outer[:, 0]]).mean() > 0.9
    assert vpm.closest_views(rotation, translation).tolist() == [view]


def test_viewpoint_cache_round_trip(viewpoint_models, lmo_models, tmp_path):
    models, cache = viewpoint_models
    files = sorted(cache.glob('*.npz'))
    assert [f.name.split('-')[0] for f in files] == sorted(NAMES)
    again = load_viewpoint_models({'ape': lmo_models['ape']}, cache, progress=False)
    np.testing.assert_array_equal(again['ape'].points, models['ape'].points)
    broken = tmp_path / 'broken.npz'
    broken.write_bytes(b'not a viewpoint model')
    with pytest.raises(InputError, match='broken.npz'):
        ViewpointModel.load(broken)
    # A cached file cut short (an interrupted copy) is rebuilt, not fatal.
    cached = next(cache.glob('ape-*.npz'))
    cached.write_bytes(cached.read_bytes()[:5000])
    rebuilt = load_viewpoint_models({'ape': lmo_models['ape']}, cache, progress=False)
    np.testing.assert_array_equal(rebuilt['ape'].points, models['ape'].points)


@pytest.mark.parametrize('name,seed', [('driller', 1), ('duck', 2), ('holepuncher', 3)])
def test_refiner_converges_on_renders(viewpoint_models, lmo_models, name, seed):
    models, _ = viewpoint_models
    model = lmo_models[name]
    rng = np.random.default_rng(seed)
    rotation = look_at_rotation(rng.normal(size=3)).T @ look_at_rotation([0, 0, -1])
    translation = np.array([0.03, -0.02, 0.75])
    image = rendered_scene(model, rotation, translation, seed)
    start_r, start_t = perturb_pose(rotation, translation, 10.0, 0.020, rng)
    config = dataclasses.replace(RefinerConfig(), iterations=20)
    result = refine_one(models[name], image, CAMERA, start_r, start_t, config)
    assert result.ok
    assert rotation_error_deg(result.rotation, rotation) < 1.0
    assert np.linalg.norm(result.translation - translation) < 0.005
    assert result.score > 0.8


def mask_over_box(silhouette, size=32, margin=0.1):
    """Make a dense net's view of a silhouette: its cells' coverage of a square around it."""
    rows, cols = np.nonzero(silhouette)
    centre = np.array([cols.mean(), rows.mean()])
    half = (1 + margin) * max(np.ptp(cols), np.ptp(rows)) / 2 + 1
    square = np.concatenate([centre - half, centre + half])
    # Coverage of each cell: the silhouette's pixels whose centres fall in it.
    i = np.floor((np.arange(CAMERA.width) - square[0]) / (2 * half) * size).astype(int)
    j = np.floor((np.arange(CAMERA.height) - square[1]) / (2 * half) * size).astype(int)
    probabilities = np.zeros((size, size))
    counts = np.zeros((size, size))
    jj, ii = np.meshgrid(j, i, indexing='ij')
    inside = (ii >= 0) & (ii < size) & (jj >= 0) & (jj < size)
    np.add.at(probabilities, (jj[inside], ii[inside]), silhouette[inside])
    np.add.at(counts, (jj[inside], ii[inside]), 1)
    return ForegroundMasks(probabilities[None] / np.maximum(counts[None], 1), square[None])


@pytest.mark.parametrize('name,seed', [('driller', 4), ('duck', 5)])
def test_a_predicted_mask_aligns_where_colours_cannot(viewpoint_models, lmo_models, name,
                                                      seed):
    models, _ = viewpoint_models
    model = lmo_models[name]
    rng = np.random.default_rng(seed)
    rotation = look_at_rotation(rng.normal(size=3)).T @ look_at_rotation([0, 0, -1])
    translation = np.array([0.02, 0.01, 0.7])
    silhouette = render_silhouette(CAMERA, model.vertices, model.faces, rotation, translation)
    bins = color_bins(np.full((CAMERA.height, CAMERA.width, 3), 128, np.uint8))  # no colours
    masks = mask_over_box(silhouette, size=64)
    starts = [perturb_pose(rotation, translation, 5.0, 0.010, rng) for _ in range(4)]
    guided = refine_poses(bins, CAMERA, [models[name]] * 4, *zip(*starts), SHIPPED,
                          masks=masks.take([0] * 4))
    alone = refine_poses(bins, CAMERA, [models[name]] * 4, *zip(*starts), SHIPPED)
    close = [rotation_error_deg(r.rotation, rotation) < 2.0
             and np.linalg.norm(r.translation - translation) < 0.005 for r in guided]
    # Most starts align (the refiner's basin, not the mask, loses the others) and score high.
    assert sum(close) >= 2, [(r.score, rotation_error_deg(r.rotation, rotation)) for r in guided]
    assert min(r.score for r, c in zip(guided, close) if c) > 0.9
    assert all(rotation_error_deg(r.rotation, rotation) > 4.0 for r in alone)   # no pull


def test_refiner_improves_perturbed_truth_on_real_frames(viewpoint_models, lmo_models,
                                                         lmo_frames):
    models, _ = viewpoint_models
    rng = np.random.default_rng(0)
    before, after = [], []
    for frame in lmo_frames[:25]:
        image = frame.load_image()
        for instance in frame.instances:
            if instance.object_name not in models or instance.visib_fract < 0.5:
                continue
            start_r, start_t = perturb_pose(instance.rotation, instance.translation, 15.0,
                                            0.020, rng)
            refined = refine_one(models[instance.object_name], image, frame.camera, start_r,
                                 start_t)
            symmetries = np.concatenate([np.eye(4)[None],
                                         lmo_models[instance.object_name].symmetries])
            before.append(cm_deg_errors(start_r, start_t, instance.rotation,
                                        instance.translation, symmetries)[0])
            after.append(cm_deg_errors(refined.rotation, refined.translation,
                                       instance.rotation, instance.translation, symmetries)[0])
    before, after = np.array(before), np.array(after)
    assert len(after) >= 30
    # Most instances get closer; a floor well below what the dev frames measure.
    assert np.mean(after < before) > 0.55
    assert np.median(after) < 13.0
    assert np.mean(after < 5.0) > 0.1


def test_bad_starts_are_reported_not_raised(viewpoint_models, lmo_frames):
    models, _ = viewpoint_models
    frame = lmo_frames[0]
    image = frame.load_image()
    ape = models['ape']
    behind = refine_one(ape, image, frame.camera, np.eye(3), [0.0, 0.0, -0.5])
    assert behind.status == 'behind_camera' and behind.score == 0.0
    outside = refine_one(ape, image, frame.camera, np.eye(3), [5.0, 5.0, 0.8])
    assert outside.status == 'outside_image' and outside.score == 0.0
    np.testing.assert_array_equal(outside.translation, [5.0, 5.0, 0.8])   # given back
    nan = refine_one(ape, image, frame.camera, np.full((3, 3), np.nan), [0.0, 0.0, 0.8])
    assert nan.status == 'behind_camera'
    with pytest.raises(InputError, match='does not match'):
        refine_one(ape, image[:100], frame.camera, np.eye(3), [0.0, 0.0, 0.8])
    with pytest.raises(InputError, match='histogram_rate'):
        RefinerConfig(histogram_rate=2.0)


def test_pipeline_refines_and_rejects_by_score(viewpoint_models, lmo_models, lmo_frames):
    models, _ = viewpoint_models
    frame = lmo_frames[0]
    image = frame.load_image()
    truths = [i for i in frame.instances if i.object_name in models and i.visib_fract > 0.5]
    detections = [Detection(i.object_name, 1.0, i.box_uv) for i in truths]
    rotations = np.stack([i.rotation for i in truths])
    pipeline = PosePipeline({n: lmo_models[n] for n in models}, SHIPPED,
                            refiner=PoseRefiner(models, SHIPPED))
    result = pipeline.estimate(image, frame.camera, detections, rotations)
    assert 'refinement' in result.timings_ms
    assert len(result.poses) == len(truths)
    assert all(0.0 < p.confidence <= 1.0 and p.refinement_score == p.confidence
               for p in result.poses)
    # A pose far from any object is scored low, and a threshold drops it.
    wrong = [PoseEstimate(detections[0], rotations[0], np.array([0.25, -0.15, 0.6]))]
    strict = PoseRefiner(models, PipelineOptions(refine_min_score=0.4))
    assert strict(image, frame.camera, wrong) == []
    assert len(strict(image, frame.camera, result.poses[:1])) == 1


def test_screening_continues_the_best_scored_candidate(viewpoint_models, lmo_frames):
    models, _ = viewpoint_models
    frame = lmo_frames[0]
    image = frame.load_image()
    rng = np.random.default_rng(3)
    truths = [i for i in frame.instances if i.object_name in models and i.visib_fract > 0.5]
    groups = []
    for truth in truths:
        detection = Detection(truth.object_name, 1.0, truth.box_uv)
        groups.append([PoseEstimate(detection, *perturb_pose(truth.rotation, truth.translation,
                                                             angle, offset, rng))
                       for angle, offset in ((60.0, 0.05), (5.0, 0.01))])
    # Without starts given back (keep_better_start), the survivor of the screening continues
    # where it stopped: the same pose as refining that candidate straight through.
    config = RefinerConfig(keep_better_start=False)
    refiner = PoseRefiner(models, SHIPPED,
                          dataclasses.replace(config, screening_iterations=3))
    assert refiner.config.screening_iterations < refiner.config.iterations
    kept = refiner.best_of(image, frame.camera, groups)
    assert len(kept) == len(groups)
    straight = PoseRefiner(models, SHIPPED, config)
    for pose, group in zip(kept, groups):
        ends = [straight(image, frame.camera, [candidate])[0] for candidate in group]
        assert any(np.allclose(pose.rotation, end.rotation, atol=1e-9)
                   and np.allclose(pose.translation, end.translation, atol=1e-9)
                   and pose.refinement_score == end.refinement_score for end in ends)
    near = [rotation_error_deg(p.rotation, t.rotation) < 10.0 for p, t in zip(kept, truths)]
    assert np.mean(near) >= 0.5


def test_a_refinement_that_lowers_the_score_gives_the_start_back(viewpoint_models, lmo_frames):
    models, _ = viewpoint_models
    frame = lmo_frames[3]
    bins = color_bins(frame.load_image())
    truths = [i for i in frame.instances if i.object_name in models]
    args = (bins, frame.camera, [models[t.object_name] for t in truths],
            [t.rotation for t in truths], [t.translation for t in truths])
    at_start = refine_poses(*args, SHIPPED, iterations=0)
    kept = refine_poses(*args, SHIPPED)
    moved = refine_poses(*args, SHIPPED, RefinerConfig(keep_better_start=False))
    for start, keep, move, truth in zip(at_start, kept, moved, truths):
        assert keep.score == max(start.score, move.score)
        if start.score > move.score:
            np.testing.assert_array_equal(keep.translation, truth.translation)


def exact_amodal_masks(frame, truths, models, size=32, context=1.25):
    """Return ForegroundMasks of the truths' own silhouettes over their squares (a perfect net)."""
    squares = square_boxes(np.stack([t.box_uv for t in truths]), context)
    masks = [render_silhouette(frame.camera.cropped(square, size), models[t.object_name].vertices,
                               models[t.object_name].faces, t.rotation, t.translation)
             for square, t in zip(squares, truths)]
    return ForegroundMasks(np.array(masks, dtype=np.float32), squares)


def test_the_mask_chooses_the_candidate_the_score_misjudges(viewpoint_models, lmo_models,
                                                            lmo_frames):
    models, _ = viewpoint_models
    picked = {0.0: [], 20.0: []}
    for frame in lmo_frames[:40:4]:
        image = frame.load_image()
        truths = [i for i in frame.instances if i.object_name in models and i.visib_fract > 0.5]
        if not truths:
            continue
        masks = exact_amodal_masks(frame, truths, lmo_models)
        rng = np.random.default_rng(frame.image_id)
        groups = [[PoseEstimate(Detection(t.object_name, 1.0, t.box_uv),
                                *perturb_pose(t.rotation, t.translation, angle, 0.01, rng))
                   for angle in (50.0, 5.0)] for t in truths]
        for weight in picked:
            kept = PoseRefiner(models, PipelineOptions(refine_mask_choice_weight=weight)).best_of(
                image, frame.camera, groups, choice_masks=masks)
            picked[weight].extend(rotation_error_deg(p.rotation, t.rotation) < 10.0
                                  for p, t in zip(kept, truths))
    assert len(picked[0.0]) >= 15
    assert np.mean(picked[20.0]) > np.mean(picked[0.0])
    with pytest.raises(InputError, match='refine_mask_choice_weight'):
        PipelineOptions(refine_mask_choice_weight=-1.0)


def test_a_refinement_that_lowers_the_merit_gives_the_start_back(viewpoint_models, lmo_models,
                                                                 lmo_frames):
    models, _ = viewpoint_models
    weight, given_back = 20.0, 0
    agreement = MaskAgreement(models)
    for frame in lmo_frames[:30:3]:
        image = frame.load_image()
        truths = [i for i in frame.instances if i.object_name in models]
        masks = exact_amodal_masks(frame, truths, lmo_models)
        starts = [PoseEstimate(Detection(t.object_name, 1.0, t.box_uv), t.rotation,
                               t.translation) for t in truths]
        kept = PoseRefiner(models, PipelineOptions(refine_mask_choice_weight=weight))(
            image, frame.camera, starts, choice_masks=masks)
        moved = PoseRefiner(models, SHIPPED)(image, frame.camera, starts)
        names = [t.object_name for t in truths]
        merit_start = np.array([r.score for r in refine_poses(
            color_bins(image), frame.camera, [models[n] for n in names],
            [t.rotation for t in truths], [t.translation for t in truths], SHIPPED,
            iterations=0, instances=range(len(truths)))]) + weight * agreement(
            frame.camera, names, [t.rotation for t in truths],
            [t.translation for t in truths], masks)
        merit_moved = np.array([p.refinement_score for p in moved]) + weight * agreement(
            frame.camera, names, [p.rotation for p in moved], [p.translation for p in moved],
            masks)
        for keep, move, truth, start, end in zip(kept, moved, truths, merit_start, merit_moved):
            if start > end:     # the mask prefers the truth: it is given back
                np.testing.assert_array_equal(keep.translation, truth.translation)
                given_back += 1
            else:
                np.testing.assert_allclose(keep.translation, move.translation)
    assert given_back >= 3


class ScriptedRefiner(PoseRefiner):
    """A PoseRefiner whose refinements and mask agreements are given: the choice alone."""

    def __init__(self, models, runs, agreement, screening_iterations):
        super().__init__(models, PipelineOptions(refine_mask_choice_weight=8.0),
                         RefinerConfig(screening_iterations=screening_iterations))
        self.runs = list(runs)      # per call of _refine, its list of Refinement
        self._agreement = lambda camera, names, rotations, translations, masks: np.array(
            [agreement(t) for t in translations])

    def _refine(self, *args, **kwargs):
        return self.runs.pop(0)


def test_the_mask_merit_never_prefers_a_failed_candidate(viewpoint_models):
    models, _ = viewpoint_models
    detection = Detection('ape', 1.0, np.array([0.0, 0.0, 50.0, 50.0]))
    starts = [PoseEstimate(detection, np.eye(3), np.array([x, 0.0, 1.0])) for x in (0.1, 0.2)]
    failed = Refinement(np.eye(3), starts[0].translation, 0.0, 'too_few_lines', start_score=0.0)
    ran = Refinement(np.eye(3), np.array([0.25, 0.0, 1.0]), 0.3, 'ok', start_score=0.2)
    masks = ForegroundMasks(np.zeros((1, 4, 4)), np.zeros((1, 4)))
    # The failed candidate's start agrees with the mask best; the one that ran is kept.
    agreement = {0.1: 0.9, 0.2: 0.1, 0.25: 0.5}
    refiner = ScriptedRefiner(models, [[failed, ran]], lambda t: agreement[round(t[0], 2)],
                              screening_iterations=100)
    kept = refiner.best_of(BLANK, CAMERA, [starts], choice_masks=masks)
    assert kept[0].source == starts[1].source and kept[0].refinement_score == 0.3
    np.testing.assert_array_equal(kept[0].translation, ran.translation)


def test_a_screened_candidate_is_judged_against_its_own_start(viewpoint_models):
    models, _ = viewpoint_models
    detection = Detection('ape', 1.0, np.array([0.0, 0.0, 50.0, 50.0]))
    starts = [PoseEstimate(detection, np.eye(3), np.array([x, 0.0, 1.0])) for x in (0.1, 0.2)]
    screening = [Refinement(np.eye(3), np.array([0.15, 0.0, 1.0]), 0.6, 'ok', start_score=0.8),
                 Refinement(np.eye(3), np.array([0.3, 0.0, 1.0]), 0.4, 'ok', start_score=0.5)]
    # The continuation starts at the screened pose (its start score 0.55); it ends lower
    # than the candidate's own start scored (0.8), so that start comes back.
    ending = [Refinement(np.eye(3), np.array([0.16, 0.0, 1.0]), 0.7, 'ok', start_score=0.55)]
    masks = ForegroundMasks(np.zeros((1, 4, 4)), np.zeros((1, 4)))
    refiner = ScriptedRefiner(models, [screening, ending], lambda t: 0.5,
                              screening_iterations=6)
    kept = refiner.best_of(BLANK, CAMERA, [starts], choice_masks=masks)
    np.testing.assert_array_equal(kept[0].translation, starts[0].translation)
    assert kept[0].refinement_score == 0.8
    # Without masks the end is kept, as before the merit.
    refiner = ScriptedRefiner(models, [screening, ending], lambda t: 0.5,
                              screening_iterations=6)
    kept = refiner.best_of(BLANK, CAMERA, [starts])
    np.testing.assert_array_equal(kept[0].translation, ending[0].translation)


def test_screening_keeps_a_failed_candidate_failed(viewpoint_models, lmo_models):
    models, _ = viewpoint_models
    rotation = look_at_rotation([0.3, -0.5, 0.8]).T
    translation = np.array([0.0, 0.0, 0.8])
    image = rendered_scene(lmo_models['duck'], rotation, translation, seed=5)
    # A 100 px window around the duck: the coarse lines (114 px) never fit, the fine ones do.
    u, v = np.round(CAMERA.project(translation[None])[0]).astype(int)
    window = CameraIntrinsics(CAMERA.fx, CAMERA.fy, CAMERA.cx - (u - 50), CAMERA.cy - (v - 50),
                              100, 100)
    crop = np.ascontiguousarray(image[v - 50:v + 50, u - 50:u + 50])
    detection = Detection('duck', 1.0, np.array([0.0, 0.0, 99.0, 99.0]))
    candidates = [PoseEstimate(detection, exp_so3(axis) @ rotation, translation)
                  for axis in ([0.05, 0.0, 0.0], [0.0, 0.05, 0.0])]
    alone = refine_one(models['duck'], crop, window, candidates[0].rotation, translation)
    assert alone.status == 'too_few_lines'
    screening = PoseRefiner(models, SHIPPED, RefinerConfig(screening_iterations=3))
    screened = screening.best_of(crop, window, [candidates])
    assert len(screened) == 1 and screened[0].refinement_score == 0.0
    np.testing.assert_array_equal(screened[0].rotation, candidates[0].rotation)


def test_tracker_follows_and_redetects_by_policy(viewpoint_models, lmo_models, lmo_frames):
    models, _ = viewpoint_models
    frame = lmo_frames[0]
    image = frame.load_image()
    truths = [i for i in frame.instances if i.object_name in models and i.visib_fract > 0.5]
    calls = []

    def detector(image_rgb):
        calls.append(1)
        return [Detection(i.object_name, 0.9, i.box_uv) for i in truths]

    def rotations(image_rgb, camera, detections):
        by_name = {i.object_name: i.rotation for i in truths}
        return np.stack([by_name[d.object_name] for d in detections])

    options = PipelineOptions(tracking=True, tracking_redetect_every=3, tracking_min_score=0.3)
    pipeline = PosePipeline({n: lmo_models[n] for n in models}, options, detector, rotations,
                            refiner=PoseRefiner(models, options))
    tracker = PoseTracker(pipeline)
    first = tracker.estimate(image, frame.camera)
    assert len(calls) == 1 and 'detector' in first.timings_ms
    assert sorted(tracker.tracks) == sorted(i.object_name for i in truths)
    second = tracker.estimate(image, frame.camera)
    assert len(calls) == 1 and 'tracking' in second.timings_ms
    # Tracks stay near the truth they started from (the image, not the truth, is what the
    # refiner fits, so they settle a little off it).
    truth = {i.object_name: i for i in truths}
    errors = [(rotation_error_deg(p.rotation, truth[p.object_name].rotation),
               np.linalg.norm(p.translation - truth[p.object_name].translation))
              for p in second.poses]
    assert len(errors) == len(truths)
    assert np.median([e[0] for e in errors]) < 8.0 and max(e[0] for e in errors) < 20.0
    assert max(e[1] for e in errors) < 0.08
    tracker.estimate(image, frame.camera)
    assert len(calls) == 1
    tracker.estimate(image, frame.camera)
    assert len(calls) == 2                # the full pipeline runs every third frame
    # An image the tracks do not fit loses them, and the full pipeline runs again.
    tracker.estimate(np.zeros_like(image), frame.camera)
    assert len(calls) == 3
    tracker.reset()
    assert tracker.tracks == {}
    with pytest.raises(InputError, match='PoseRefiner'):
        PoseTracker(PosePipeline(pipeline.models, PipelineOptions(refine=False), detector,
                                 rotations))


def test_pipeline_with_refiner_and_no_detections(viewpoint_models, lmo_models, lmo_frames):
    models, _ = viewpoint_models
    frame = lmo_frames[0]
    options = PipelineOptions(refine_hypotheses=2)
    pipeline = PosePipeline({n: lmo_models[n] for n in models}, options, lambda image: [],
                            lambda *args: np.zeros((0, 3, 3)),
                            refiner=PoseRefiner(models, options))
    assert pipeline.estimate(frame.load_image(), frame.camera).poses == []
    assert PoseRefiner(models, options)(frame.load_image(), frame.camera, []) == []


class TruthCorrespondences:
    """A dense stage that knows the truth: PnP poses and amodal masks of the instances."""

    def __init__(self, frame, models):
        self.frame, self.models = frame, models

    def __call__(self, image_rgb, camera, detections):
        truths = {i.object_name: i for i in self.frame.instances}
        poses, masks = [], []
        for detection in detections:
            truth = truths[detection.object_name]
            model = self.models[detection.object_name]
            poses.append(DensePose(truth.rotation, truth.translation, 100, 100))
            masks.append(mask_over_box(render_silhouette(
                camera, model.vertices, model.faces, truth.rotation, truth.translation)))
        probabilities = np.concatenate([m.probabilities for m in masks])
        squares = np.concatenate([m.squares_uv for m in masks])
        maps = DenseMaps(np.zeros(probabilities.shape + (3,)), probabilities, probabilities,
                         squares)
        return maps, poses


def test_pnp_poses_are_candidates_and_say_so(viewpoint_models, lmo_models, lmo_frames):
    models, _ = viewpoint_models
    frame = next(f for f in lmo_frames if {'ape', 'duck'} <= {i.object_name
                                                              for i in f.instances})
    objects = {n: lmo_models[n] for n in ('ape', 'duck')}
    detections = [Detection(i.object_name, 1.0, i.box_uv) for i in frame.instances
                  if i.object_name in objects]
    oracle = TruthCorrespondences(frame, objects)
    plain = PosePipeline(objects, PipelineOptions(refine=False, pose_source='dense',
                                                  dense_translation='pnp'),
                         correspondences=oracle)
    result = plain.estimate(frame.load_image(), frame.camera, detections)
    assert [p.source for p in result.poses] == ['pnp'] * len(detections)
    assert 'correspondences' in result.timings_ms
    truths = {i.object_name: i for i in frame.instances}
    for pose in result.poses:
        np.testing.assert_array_equal(pose.translation, truths[pose.object_name].translation)
    # Refined with the masks of the truth, right poses stay right (5 cm / 5 deg; a
    # silhouette holds out-of-plane rotation loosely); the equation's translation from PnP's
    # rotation is a second candidate.
    options = PipelineOptions(pose_source='dense', dense_translation='both',
                              dense_mask='amodal')
    refined = PosePipeline(objects, options,
                           refiner=PoseRefiner({n: models[n] for n in objects}, options),
                           correspondences=oracle).estimate(
        frame.load_image(), frame.camera, detections)
    assert {p.source for p in refined.poses} <= {'pnp', 'pnp_rotation'}
    for pose in refined.poses:
        truth = truths[pose.object_name]
        assert rotation_error_deg(pose.rotation, truth.rotation) < 5.0
        assert np.linalg.norm(pose.translation - truth.translation) < 0.05


def test_the_start_prior_holds_what_the_lines_hardly_constrain(viewpoint_models, lmo_frames):
    models, _ = viewpoint_models
    frame = lmo_frames[2]
    bins = color_bins(frame.load_image())
    truths = [i for i in frame.instances if i.object_name in models and i.visib_fract > 0.3]
    args = (bins, frame.camera, [models[t.object_name] for t in truths],
            [t.rotation for t in truths], [t.translation for t in truths])
    config = RefinerConfig(keep_better_start=False)
    moved = refine_poses(*args, PipelineOptions(refine_prior_deg=0.0), config)
    kept = refine_poses(*args, PipelineOptions(refine_prior_deg=0.02), config)
    turned = [rotation_error_deg(r.rotation, t.rotation) for r, t in zip(moved, truths)]
    # Started at the truth, the contour lines alone turn real poses off by degrees; a
    # rotation prior of 0.02 deg holds every rotation, not the translation.
    assert np.median(turned) > 1.0
    for result, truth in zip(kept, truths):
        assert result.ok
        assert rotation_error_deg(result.rotation, truth.rotation) < 0.1
    assert max(np.linalg.norm(r.translation - t.translation)
               for r, t in zip(kept, truths)) > 1e-3
    with pytest.raises(InputError, match='refine_prior_mm'):
        PipelineOptions(refine_prior_mm=-1.0)


def _frame_lines(viewpoint_models, lmo_frames, scale):
    """Return the region modality, poses, lines and frame of a real frame's true poses."""
    models, _ = viewpoint_models
    frame = lmo_frames[0]
    instances = [i for i in frame.instances if i.object_name in models]
    rotation = np.stack([i.rotation for i in instances])
    translation = np.stack([i.translation for i in instances])
    modality = RegionModality([models[i.object_name] for i in instances],
                              color_bins(frame.load_image()), frame.camera, 3.0)
    hist_f, hist_b, _ = modality.line_colors(rotation, translation)
    lines = modality.lines(rotation, translation, hist_f, hist_b, scale)
    return modality, rotation, translation, lines, frame


def test_line_colours_count_the_pixels_beside_each_contour(viewpoint_models, lmo_frames):
    modality, rotation, translation, _, frame = _frame_lines(viewpoint_models, lmo_frames, 1)
    hist_f, hist_b, seen = modality.line_colors(rotation, translation)
    _, centres, normals, runs_f, runs_b, in_front = modality.project(rotation, translation)
    bins = color_bins(frame.load_image())
    height, width = bins.shape
    for n in range(len(rotation)):
        expected = []
        for sign, runs in ((-1.0, runs_f), (1.0, runs_b)):
            colours = []
            for k in np.flatnonzero(in_front[n]):
                for offset in np.arange(0.5, min(runs[n, k] - 1.0, 20.0), 2.0):
                    u, v = (np.float32(centres[n, k] + 0.5)
                            + np.float32(sign * offset) * normals[n, k].astype(np.float32))
                    if 0 <= u < width and 0 <= v < height:
                        colours.append(bins[int(v), int(u)])
            expected.append(np.bincount(colours, minlength=hist_f.shape[1]) / len(colours))
        np.testing.assert_allclose(hist_f[n], expected[0], atol=1e-12)
        np.testing.assert_allclose(hist_b[n], expected[1], atol=1e-12)
        assert seen[n]


def test_lines_find_a_colour_step_where_it_is():
    # A red object left of the pixel edge u = 299.5 on a blue ground; the colour model knows
    # both colours.
    camera = CameraIntrinsics(500.0, 500.0, 199.5, 239.5, 640, 480)
    image = np.zeros((camera.height, camera.width, 3), np.uint8)
    image[:, :300] = (200, 30, 30)
    image[:, 300:] = (30, 30, 200)
    bins = color_bins(image)
    hist_f, hist_b = np.zeros((1, 4096)), np.zeros((1, 4096))
    hist_f[0, bins[0, 0]], hist_b[0, bins[0, -1]] = 1.0, 1.0
    # A model's straight right side seen head-on, projected at u = 299.5 + shift_px.
    model = ViewpointModel(np.array([[0.0, 0.0, -1.0]]),
                           np.array([[[0.05, y, 0.0] for y in np.linspace(-0.05, 0.05, 20)]],
                                    np.float32),
                           np.tile(np.float32([1.0, 0.0, 0.0]), (1, 20, 1)),
                           np.full((1, 20), 0.1, np.float32), np.full((1, 20), 0.1, np.float32),
                           0.14)
    for shift_px, scale in ((0.2, 1), (3.3, 1), (-4.0, 2), (9.0, 6), (-10.6, 4)):
        depth = 0.05 * camera.fx / (299.5 + shift_px - camera.cx)
        modality = RegionModality([model], bins, camera, 3.0)
        lines = modality.lines(np.eye(3)[None], np.array([[0.0, 0.0, depth]]), hist_f,
                               hist_b, scale)
        assert lines.valid.all()
        # The step lies shift_px / scale segments inside the projected contour; a sharp one
        # is placed between two segments (the distribution's positions are half-integers).
        np.testing.assert_allclose(lines.mean, -shift_px / scale, atol=0.52)


def test_line_pull_is_the_derivative_of_the_contour_offsets(viewpoint_models, lmo_frames):
    modality, rotation, translation, lines, frame = _frame_lines(viewpoint_models, lmo_frames,
                                                                 2)
    scale, sigma = 2, 3.5
    gradient, hessian = modality.gradient_hessian(rotation, translation, lines, scale, sigma)
    camera = frame.camera

    def offsets(n, theta):
        """(P,) each line's projected point along its normal, segments, after theta."""
        turned = rotation[n] @ exp_so3(theta[:3])
        points = lines.points_model[n] @ turned.T + translation[n] + rotation[n] @ theta[3:]
        uv = np.stack([camera.fx * points[:, 0] / points[:, 2] + camera.cx,
                       camera.fy * points[:, 1] / points[:, 2] + camera.cy], axis=1)
        return np.sum((uv - lines.centres_uv[n]) * lines.normals_uv[n], axis=1) / scale

    for n in range(len(rotation)):
        steps = np.eye(6) * np.array([1e-5] * 3 + [1e-6] * 3)
        jacobian = np.stack([(offsets(n, h) - offsets(n, -h)) / (2 * h.max())
                             for h in steps], axis=1)
        weight = np.where(lines.valid[n], MIN_VARIANCE / (sigma / scale) ** 2
                          / lines.variance[n], 0.0)
        residual = lines.mean[n] - offsets(n, np.zeros(6))
        np.testing.assert_allclose(gradient[n], (weight * residual) @ jacobian,
                                   rtol=1e-4, atol=1e-6 * np.abs(gradient[n]).max())
        np.testing.assert_allclose(hessian[n], (jacobian * weight[:, None]).T @ jacobian,
                                   rtol=1e-4, atol=1e-6 * np.abs(hessian[n]).max())


def test_threads_split_the_poses_without_changing_them(viewpoint_models, lmo_frames):
    models, _ = viewpoint_models
    frame = lmo_frames[3]
    instances = [i for i in frame.instances if i.object_name in models]
    rng = np.random.default_rng(7)
    starts = [perturb_pose(i.rotation, i.translation, 10.0, 0.01, rng) for i in instances]
    runs = [refine_poses(color_bins(frame.load_image()), frame.camera,
                         [models[i.object_name] for i in instances], [r for r, _ in starts],
                         [t for _, t in starts], PipelineOptions(refine_threads=threads))
            for threads in (1, 2)]
    for one, two in zip(*runs):
        assert one.status == two.status == 'ok'
        np.testing.assert_array_equal(one.rotation, two.rotation)
        np.testing.assert_array_equal(one.translation, two.translation)


def test_nearer_instances_hide_the_contour_they_cover(viewpoint_models, lmo_models,
                                                      lmo_frames):
    models, _ = viewpoint_models
    hidden_any = False
    for frame in lmo_frames[:10]:
        instances = [i for i in frame.instances if i.object_name in models]
        if len(instances) < 2:
            continue
        rotation = np.stack([i.rotation for i in instances])
        translation = np.stack([i.translation for i in instances])
        bins = color_bins(frame.load_image())
        view = [models[i.object_name] for i in instances]
        free = RegionModality(view, bins, frame.camera, 3.0).project(rotation, translation)
        count = len(instances)
        hiding = RegionModality(view, bins, frame.camera, 3.0, occlusions=(
            np.arange(count), np.ones(count, bool))).project(rotation, translation)
        centres, seen, seen_free = free[1], hiding[5], free[5]
        hidden = seen_free & ~seen
        silhouettes = [cv2.dilate(render_silhouette(frame.camera, lmo_models[i.object_name]
                                                    .vertices, lmo_models[i.object_name].faces,
                                                    i.rotation, i.translation)
                                  .astype(np.uint8), np.ones((5, 5), np.uint8))
                       for i in instances]
        for n in range(count):
            nearer = [m for m in range(count) if translation[m, 2] < translation[n, 2]]
            pixels = np.round(centres[n]).astype(int)
            u = np.clip(pixels[:, 0], 0, frame.camera.width - 1)
            v = np.clip(pixels[:, 1], 0, frame.camera.height - 1)
            covered = np.zeros(len(u), bool)
            for m in nearer:
                covered |= silhouettes[m][v, u] > 0
            # Hidden points lie on a nearer instance's silhouette (within 2 px: the lines
            # come from the closest stored view); the farthest is never hidden.
            assert np.all(covered[hidden[n]]), (frame.image_id, n)
            hidden_any |= hidden[n].any()
        assert not hidden[np.argmin(translation[:, 2])].any()
        # Candidates of one instance never hide each other.
        twice = RegionModality(view + view, bins, frame.camera, 3.0, occlusions=(
            np.tile(np.arange(count), 2), np.ones(2 * count, bool)))
        both = twice.project(np.concatenate([rotation, rotation]),
                             np.concatenate([translation, translation]))[5]
        np.testing.assert_array_equal(both[:count], seen)
        np.testing.assert_array_equal(both[count:], seen)
    assert hidden_any


def _inside_even_odd(u, v, polygon):
    """(K,) bool: inside the closed (P, 2) polygon by the even-odd rule, every edge read."""
    inside = np.zeros(len(u), bool)
    for (u_i, v_i), (u_j, v_j) in zip(polygon, np.roll(polygon, 1, axis=0)):
        crossing = (v_i > v) != (v_j > v)
        with np.errstate(divide='ignore', invalid='ignore'):
            inside ^= crossing & (u < (u_j - u_i) * (v - v_i) / (v_j - v_i) + u_i)
    return inside


def test_occluders_hide_exactly_the_points_inside_their_outline():
    # A concave star outline (spikes thinner than its bands) hides two farther outlines:
    # another star, and the occluder's own vertices moved sideways, points on the rows of
    # its edges' ends, where an edge's band and a point's meet.
    rng = np.random.default_rng(3)
    points, hidden = 200, 0
    angle = np.linspace(0.0, 2.0 * np.pi, points, endpoint=False)
    for trial in range(20):
        radius = rng.uniform(20.0, 80.0, (2, 1)) * (1.0 + 0.6 * np.sin(
            rng.integers(3, 40, (2, 1)) * angle + rng.uniform(0, 6, (2, 1))))
        centre = rng.uniform(100.0, 200.0, (2, 2))
        stars = np.stack([centre[:, None, 0] + radius * np.cos(angle),
                          centre[:, None, 1] + radius * np.sin(angle)], axis=-1)
        beside = stars[0] + np.stack([rng.uniform(-3.0, 3.0, points), np.zeros(points)], 1)
        centres = np.concatenate([stars, beside[None]])
        in_front = np.ones((3, points), bool)
        contour_projection.hide_occluded(centres, np.array([1.0, 2.0, 3.0]), np.arange(3),
                                         np.array([True, False, False]), in_front)
        assert in_front[0].all()        # the nearer one is never hidden
        for target in (1, 2):
            expected = _inside_even_odd(centres[target, :, 0], centres[target, :, 1],
                                        centres[0])
            np.testing.assert_array_equal(~in_front[target], expected,
                                          err_msg=f'trial {trial}, outline {target}')
            hidden += expected.sum()
    assert 0 < hidden < 20 * 2 * points * 3 / 4
