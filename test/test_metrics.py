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

"""Pose metrics against hand-computed cases and their properties."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bbpose_ros.core.eval import metrics

CUBE = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * 0.05
K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
T = np.array([0.0, 0.0, 1.0])


def test_add_of_a_pure_offset_is_its_length():
    assert metrics.add(np.eye(3), T + [0.03, 0.04, 0], np.eye(3), T, CUBE) == pytest.approx(0.05)
    assert metrics.te(T + [0.03, 0.04, 0], T) == pytest.approx(0.05)


def test_proj_of_a_sideways_offset_is_f_times_offset_over_depth():
    error = metrics.proj(np.eye(3), T + [0.01, 0, 0], np.eye(3), T, K, CUBE[:1] * 0)
    assert error == pytest.approx(500.0 * 0.01 / 1.0)


def test_adi_ignores_a_symmetry_and_never_exceeds_add():
    quarter = Rotation.from_euler('z', 90, degrees=True).as_matrix()
    assert metrics.adi(quarter, T, np.eye(3), T, CUBE) == pytest.approx(0.0, abs=1e-12)
    assert metrics.add(quarter, T, np.eye(3), T, CUBE) > 0.05
    rng = np.random.default_rng(0)
    for r in Rotation.random(20, random_state=rng).as_matrix():
        t = T + rng.normal(scale=0.02, size=3)
        assert metrics.adi(r, t, np.eye(3), T, CUBE) <= metrics.add(r, t, np.eye(3), T, CUBE)


def test_re_and_recall():
    turn = Rotation.from_euler('y', 4, degrees=True).as_matrix()
    assert metrics.re(turn, np.eye(3)) == pytest.approx(4.0)
    assert metrics.recall([1.0, 6.0, np.nan, 2.0], 5.0) == pytest.approx(0.5)


@pytest.mark.parametrize('name', ['eggbox', 'glue'])
def test_symmetric_objects_score_zero_at_a_symmetric_equivalent(lmo_models, name):
    model = lmo_models[name]
    rotation = Rotation.from_euler('xyz', [20, -30, 50], degrees=True).as_matrix()
    t = np.array([0.05, -0.02, 0.8])
    sym_rotations, sym_translations = metrics.symmetric_ground_truths(
        rotation, t, model.symmetry_transforms)
    est_r, est_t = sym_rotations[1], sym_translations[1]
    # The equivalent pose is far in ADD (a half turn) but ~0 in ADD-S, re and te.
    assert metrics.add(est_r, est_t, rotation, t, model.eval_points) > 0.1 * model.diameter
    # The mesh is only nearly symmetric: a few mm remain, far below the 0.1 d threshold.
    assert metrics.adi(est_r, est_t, rotation, t, model.eval_points) < 0.02 * model.diameter
    re_deg, te_m = metrics.cm_deg_errors(est_r, est_t, rotation, t, model.symmetry_transforms)
    assert re_deg < 0.5 and te_m < 1e-9     # models_info rounds S to 6 digits
