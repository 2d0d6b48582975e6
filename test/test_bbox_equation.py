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

"""The Bounding Box Equation on exact synthetic boxes and on real LM-O annotations."""

from hypothesis import given, settings, strategies as st
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bbpose_ros.core.geometry.bbox_equation import pad_point_sets, SELECTIONS, solve_translations
from bbpose_ros.core.geometry.camera import CameraIntrinsics

CAMERA = CameraIntrinsics(572.4114, 573.57043, 325.2611, 242.04899, 640, 480)
OBJECTS = ('ape', 'driller', 'glue', 'holepuncher')


def exact_boxes(rotations, translations, points):
    """[u_min, v_min, u_max, v_max] of the projected points: the box a perfect detector gives."""
    cam = np.einsum('nij,nmj->nmi', rotations, points) + translations[:, None, :]
    uv = CAMERA.project(cam)
    return np.concatenate([uv.min(axis=1), uv.max(axis=1)], axis=1)


def random_poses(seed, count):
    """Rotations and translations (0.3-1.5 m away, inside a wide cone) from a seed."""
    rng = np.random.default_rng(seed)
    rotations = Rotation.random(count, random_state=rng).as_matrix()
    z = rng.uniform(0.3, 1.5, count)
    xy = rng.uniform(-0.4, 0.4, (count, 2)) * z[:, None]
    return rotations, np.column_stack([xy, z])


@pytest.mark.parametrize('selection', SELECTIONS)
@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_recovers_translation_exactly(lmo_models, selection, seed):
    rotations, translations = random_poses(seed, len(OBJECTS))
    points = pad_point_sets([lmo_models[name].hull_points for name in OBJECTS])
    boxes = exact_boxes(rotations, translations, points)
    solution = solve_translations(rotations, boxes, points, CAMERA.fx, CAMERA.fy, CAMERA.cx,
                                  CAMERA.cy, selection=selection)
    np.testing.assert_allclose(solution.translations, translations, atol=1e-6)
    np.testing.assert_allclose(solution.side_residuals_px, 0.0, atol=1e-6)
    assert solution.converged.all()
    assert (solution.iterations <= 10).all()


@pytest.mark.parametrize('selection', SELECTIONS)
def test_side_residuals_measure_how_far_the_pose_misses_each_side(lmo_models, selection):
    rotations, translations = random_poses(5, len(OBJECTS))
    points = pad_point_sets([lmo_models[name].hull_points for name in OBJECTS])
    boxes = exact_boxes(rotations, translations, points)
    boxes[:, 2] += 12.0                       # the right side 12 px too far: no t fits all four
    solution = solve_translations(rotations, boxes, points, CAMERA.fx, CAMERA.fy, CAMERA.cx,
                                  CAMERA.cy, selection=selection)
    cam = np.einsum('nij,nmj->nmi', rotations, points) + solution.translations[:, None, :]
    uv = CAMERA.project(cam)
    reprojected = np.concatenate([uv.min(axis=1), uv.max(axis=1)], axis=1)
    # Each residual is close to the solved pose's own box side minus the given one (its
    # touching point need not stay the extreme one once the sides disagree), and least
    # squares spreads the 12 px over the four sides.
    np.testing.assert_allclose(solution.side_residuals_px, reprojected - boxes, rtol=0.15,
                               atol=0.05)
    assert (np.abs(solution.side_residuals_px).max(axis=1) > 2.0).all()
    assert (np.abs(solution.side_residuals_px).max(axis=1) < 12.0).all()


def test_hull_points_give_the_same_translation_as_all_vertices(lmo_models):
    model = lmo_models['cat']
    rotations, translations = random_poses(7, 20)
    every = np.repeat(model.vertices[None], 20, axis=0)
    hull = np.repeat(model.hull_points[None], 20, axis=0)
    boxes = exact_boxes(rotations, translations, every)
    args = (CAMERA.fx, CAMERA.fy, CAMERA.cx, CAMERA.cy)
    np.testing.assert_allclose(solve_translations(rotations, boxes, hull, *args).translations,
                               solve_translations(rotations, boxes, every, *args).translations,
                               atol=1e-9)


@pytest.mark.parametrize('selection', SELECTIONS)
def test_one_dropped_side_still_determines_translation(lmo_models, selection):
    rotations, translations = random_poses(3, len(OBJECTS))
    points = pad_point_sets([lmo_models[name].hull_points for name in OBJECTS])
    boxes = exact_boxes(rotations, translations, points)
    boxes[:, 2] += 40.0                       # the right side is wrong (e.g. cut) ...
    weights = np.array([[1.0, 1.0, 0.0, 1.0]] * len(OBJECTS))   # ... and ignored
    solution = solve_translations(rotations, boxes, points, CAMERA.fx, CAMERA.fy, CAMERA.cx,
                                  CAMERA.cy, side_weights=weights, selection=selection)
    np.testing.assert_allclose(solution.translations, translations, atol=1e-6)


def test_iterations_are_bounded(lmo_models):
    rotations, translations = random_poses(11, 50)
    points = np.repeat(lmo_models['driller'].hull_points[None], 50, axis=0)
    boxes = exact_boxes(rotations, translations, points)
    solution = solve_translations(rotations, boxes, points, CAMERA.fx, CAMERA.fy, CAMERA.cx,
                                  CAMERA.cy, selection='direct_then_perspective',
                                  max_iterations=1)
    assert (solution.iterations <= 1).all()


def real_instance_solutions(frames, models, **options):
    """Solve every LM-O instance with true rotation and bbox_obj; (translations, truth, cut)."""
    found, truths, cut = [], [], []
    for frame in frames:
        instances = [i for i in frame.instances if i.visib_fract >= 0.1]
        rotations = np.stack([i.rotation for i in instances])
        boxes = np.stack([i.box_uv for i in instances])
        points = pad_point_sets([models[i.object_name].hull_points for i in instances])
        camera = frame.camera
        solution = solve_translations(rotations, boxes, points, camera.fx, camera.fy,
                                      camera.cx, camera.cy, **options)
        found.append(solution.translations)
        truths.append(np.stack([i.translation for i in instances]))
        cut.extend((b[0] < -0.5) | (b[1] < -0.5) | (b[2] > camera.width - 0.5)
                   | (b[3] > camera.height - 0.5) for b in boxes)
    return np.concatenate(found), np.concatenate(truths), np.array(cut)


def real_instance_errors(frames, models, **options):
    """Errors (m) on LM-O with true rotation and bbox_obj, and which boxes the border cut."""
    found, truth, cut = real_instance_solutions(frames, models, **options)
    return np.linalg.norm(found - truth, axis=1), cut


@pytest.mark.parametrize('selection', SELECTIONS)
def test_real_lmo_frames_with_ground_truth_rotation(lmo_frames, lmo_models, selection):
    errors, cut = real_instance_errors(lmo_frames, lmo_models, selection=selection)
    assert len(errors) > 700
    assert np.median(errors) <= 0.010
    assert errors[~cut].max() < 0.050


def test_perspective_reselection_beats_direct_conversion_alone(lmo_frames, lmo_models):
    iterated, _ = real_instance_errors(lmo_frames, lmo_models,
                                       selection='direct_then_perspective', max_iterations=10)
    direct, _ = real_instance_errors(lmo_frames, lmo_models,
                                     selection='direct_then_perspective', max_iterations=0)
    assert iterated.max() < direct.max()
    assert np.median(iterated) <= np.median(direct) + 1e-9


def test_tangent_planes_reach_the_iterations_fixed_point(lmo_frames, lmo_models):
    tangent, _, _ = real_instance_solutions(lmo_frames, lmo_models, selection='tangent_planes')
    iterated, _, _ = real_instance_solutions(lmo_frames, lmo_models,
                                             selection='direct_then_perspective')
    assert np.linalg.norm(tangent - iterated, axis=1).max() < 1e-4      # 0.1 mm


def test_unknown_selection_is_refused():
    with pytest.raises(ValueError, match='selection must be one of'):
        solve_translations(np.eye(3)[None], np.array([[0.0, 0.0, 10.0, 10.0]]),
                           np.zeros((1, 2, 3)), 500.0, 500.0, 320.0, 240.0, selection='guess')


@pytest.mark.parametrize('size', [(640, 480), (320, 240)])
def test_solution_does_not_depend_on_image_scale(lmo_models, size):
    camera = CAMERA.scaled(*size)
    rotations, translations = random_poses(5, 4)
    points = pad_point_sets([lmo_models[name].hull_points for name in OBJECTS])
    cam = np.einsum('nij,nmj->nmi', rotations, points) + translations[:, None, :]
    uv = camera.project(cam)
    boxes = np.concatenate([uv.min(axis=1), uv.max(axis=1)], axis=1)
    solution = solve_translations(rotations, boxes, points, camera.fx, camera.fy, camera.cx,
                                  camera.cy)
    np.testing.assert_allclose(solution.translations, translations, atol=1e-6)
