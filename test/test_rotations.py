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

"""Quaternion conventions, rotation errors and the allocentric/egocentric views."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bbpose_ros.core.geometry import rotations as rot
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.util.errors import InputError

MATRICES = Rotation.random(200, random_state=1).as_matrix()


def test_quaternion_matrix_round_trip_and_hemisphere():
    q = rot.matrix_to_quat_wxyz(MATRICES)
    assert q.shape == (200, 4)
    assert (q[:, 0] >= 0).all()
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(rot.quat_wxyz_to_matrix(q), MATRICES, atol=1e-12)
    np.testing.assert_allclose(rot.quat_wxyz_to_matrix(-q), MATRICES, atol=1e-12)


def test_ros_order_matches_scipy_scalar_last():
    q_xyzw = Rotation.from_matrix(MATRICES).as_quat()
    np.testing.assert_allclose(rot.quat_wxyz_to_matrix(rot.xyzw_to_wxyz(q_xyzw)), MATRICES,
                               atol=1e-12)
    np.testing.assert_allclose(rot.wxyz_to_xyzw(rot.xyzw_to_wxyz(q_xyzw)), q_xyzw)
    # A 90 degree turn about z: (w, x, y, z) = (cos 45, 0, 0, sin 45).
    s = np.sqrt(0.5)
    np.testing.assert_allclose(rot.quat_wxyz_to_matrix([s, 0, 0, s]),
                               [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)


def test_positive_hemisphere_flips_only_negative_q0():
    q = np.array([[-0.5, 0.5, 0.5, 0.5], [0.5, -0.5, 0.5, 0.5]])
    np.testing.assert_allclose(rot.positive_hemisphere(q),
                               [[0.5, -0.5, -0.5, -0.5], [0.5, -0.5, 0.5, 0.5]])


def test_rotation_error_is_the_relative_angle():
    turn = Rotation.from_rotvec([0.0, 0.0, np.radians(30.0)]).as_matrix()
    assert rot.rotation_error_deg(turn @ MATRICES[0], MATRICES[0]) == pytest.approx(30.0)
    assert rot.rotation_error_deg(MATRICES[0], MATRICES[0]) == pytest.approx(0.0, abs=1e-5)


def test_euler_error_of_a_turn_about_x():
    turn = Rotation.from_euler('xyz', [10.0, 0.0, 0.0], degrees=True).as_matrix()
    assert rot.euler_error_deg(turn, np.eye(3))[0] == pytest.approx(10.0 / 3.0)
    assert rot.euler_error_deg(MATRICES, MATRICES).max() == pytest.approx(0.0, abs=1e-9)


def test_quaternion_product_composes_rotations_at_any_length():
    rng = np.random.default_rng(3)
    p, q = rng.normal(size=(2, 50, 4))
    product = rot.quat_multiply(p, q)
    np.testing.assert_allclose(rot.quat_wxyz_to_matrix(product),
                               rot.quat_wxyz_to_matrix(p) @ rot.quat_wxyz_to_matrix(q),
                               atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(product, axis=1),
                               np.linalg.norm(p, axis=1) * np.linalg.norm(q, axis=1))
    composed = Rotation.from_quat(rot.wxyz_to_xyzw(p)) * Rotation.from_quat(rot.wxyz_to_xyzw(q))
    unit = product / np.linalg.norm(product, axis=1, keepdims=True)
    np.testing.assert_allclose(rot.positive_hemisphere(unit),
                               rot.positive_hemisphere(rot.xyzw_to_wxyz(composed.as_quat())),
                               atol=1e-12)


def test_allocentric_round_trip_and_optical_axis_identity():
    rays = np.random.default_rng(0).normal(size=(200, 3)) * [0.4, 0.3, 0.0] + [0, 0, 1]
    allo = rot.egocentric_to_allocentric(MATRICES, rays)
    np.testing.assert_allclose(rot.allocentric_to_egocentric(allo, rays), MATRICES, atol=1e-12)
    on_axis = rot.allocentric_to_egocentric(MATRICES[:3], [[0, 0, 1]] * 3)
    np.testing.assert_allclose(on_axis, MATRICES[:3], atol=1e-12)
    views = rot.ray_rotation(rays)
    unit = rays / np.linalg.norm(rays, axis=1, keepdims=True)
    np.testing.assert_allclose(views @ [0.0, 0.0, 1.0], unit, atol=1e-12)
    # The smallest such rotation: about z x r by the angle between z and r.
    axis = np.cross([0.0, 0.0, 1.0], unit)
    angle = np.arctan2(np.linalg.norm(axis, axis=1), unit[:, 2])
    rotvec = axis / np.linalg.norm(axis, axis=1, keepdims=True) * angle[:, None]
    np.testing.assert_allclose(views, Rotation.from_rotvec(rotvec).as_matrix(), atol=1e-12)


def test_camera_from_k_p_and_scaling():
    k = [[572.4, 0, 325.3], [0, 573.6, 242.0], [0, 0, 1]]
    camera = CameraIntrinsics.from_k(k, 640, 480)
    p = np.hstack([np.array(k), np.zeros((3, 1))])
    assert CameraIntrinsics.from_p(p, 640, 480) == camera
    half = camera.scaled(320, 240)
    point = np.array([0.1, -0.05, 0.8])
    # Pixel edges scale by 1/2: u_half + 0.5 = (u + 0.5) / 2.
    np.testing.assert_allclose(half.project(point) + 0.5, (camera.project(point) + 0.5) / 2)
    np.testing.assert_allclose(camera.normalized(camera.project(point)), point[:2] / point[2])
    with pytest.raises(InputError, match='fx'):
        CameraIntrinsics.from_k(np.zeros((3, 3)), 640, 480)


def test_exp_so3_turns_about_the_vector_by_its_length():
    rng = np.random.default_rng(7)
    for magnitude in (0.0, 1e-9, 1e-5, 1e-3, 0.5, 3.0):
        vectors = rng.normal(size=(20, 3))
        vectors *= magnitude / np.linalg.norm(vectors, axis=1, keepdims=True)
        matrices = rot.exp_so3(vectors)
        np.testing.assert_allclose(matrices @ np.swapaxes(matrices, 1, 2),
                                   np.broadcast_to(np.eye(3), (20, 3, 3)), atol=1e-12)
        np.testing.assert_allclose(np.linalg.det(matrices), 1.0, atol=1e-12)
        # The axis stays put, and the angle is the vector's length.
        np.testing.assert_allclose((matrices @ vectors[..., None])[..., 0], vectors,
                                   atol=1e-12)
        angles = np.arccos(np.clip((np.trace(matrices, axis1=1, axis2=2) - 1) / 2, -1, 1))
        np.testing.assert_allclose(angles, magnitude, atol=1e-7)
        np.testing.assert_allclose(rot.exp_so3(vectors[0]), matrices[0], atol=1e-15)
    assert rot.exp_so3(np.zeros((2, 4, 3))).shape == (2, 4, 3, 3)


def test_log_so3_inverts_exp_so3_below_half_a_turn():
    rng = np.random.default_rng(8)
    for magnitude in (0.0, 1e-6, 0.3, 3.0):
        vectors = rng.normal(size=(20, 3))
        vectors *= magnitude / np.linalg.norm(vectors, axis=1, keepdims=True)
        np.testing.assert_allclose(rot.log_so3(rot.exp_so3(vectors)), vectors, atol=1e-9)
    # Past half a turn the shorter way round comes back: the same rotation.
    long_way = np.array([0.0, 0.0, 1.5 * np.pi])
    np.testing.assert_allclose(rot.log_so3(rot.exp_so3(long_way)), [0.0, 0.0, -0.5 * np.pi],
                               atol=1e-12)
    assert rot.log_so3(np.eye(3)[None, None].repeat(2, 1)).shape == (1, 2, 3)


def test_nearest_rotation_projects_onto_so3():
    rng = np.random.default_rng(3)
    noisy = MATRICES[:50] * rng.uniform(0.997, 1.003, (50, 1, 1)) \
        + rng.normal(0, 1e-4, (50, 3, 3))
    projected = rot.nearest_rotation(noisy)
    np.testing.assert_allclose(projected @ np.swapaxes(projected, 1, 2),
                               np.broadcast_to(np.eye(3), (50, 3, 3)), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(projected), 1.0, atol=1e-12)
    assert rot.rotation_error_deg(projected, MATRICES[:50]).max() < 0.05
    np.testing.assert_allclose(rot.nearest_rotation(MATRICES), MATRICES, atol=1e-12)
    # Scaled by 1.003, a rotation 5.5 deg off reads under 5 deg off the trace; projected, not.
    turned = rot.exp_so3([0.0, 0.0, np.radians(5.5)]) @ MATRICES[0]
    assert rot.rotation_error_deg(turned, 1.003 * MATRICES[0]) < 5.0
    assert rot.rotation_error_deg(turned, rot.nearest_rotation(1.003 * MATRICES[0])) > 5.4


@pytest.mark.parametrize('direction', rot.PERTURB_DIRECTIONS)
def test_perturb_pose_moves_exactly_and_along_the_ray_when_asked(direction):
    rng = np.random.default_rng(4)
    translation = np.array([0.1, -0.05, 0.9])
    moves = []
    for rotation in MATRICES[:20]:
        turned, moved = rot.perturb_pose(rotation, translation, 12.0, 0.03, rng, direction)
        assert rot.rotation_error_deg(turned, rotation) == pytest.approx(12.0)
        assert np.linalg.norm(moved - translation) == pytest.approx(0.03)
        moves.append(moved - translation)
    along = np.array(moves) @ translation / np.linalg.norm(translation) / 0.03
    if direction == 'ray':      # towards and away from the camera, never sideways
        np.testing.assert_allclose(np.abs(along), 1.0)
        assert (along > 0).any() and (along < 0).any()
    else:
        assert np.abs(along).max() < 0.999
    with pytest.raises(InputError, match='perturbation direction'):
        rot.perturb_pose(MATRICES[0], translation, 1.0, 0.01, rng, 'sideways')
