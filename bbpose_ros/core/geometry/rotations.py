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
Rotations: unit quaternions, matrices, errors and the allocentric/egocentric views.

Quaternion order is named in every function: ``wxyz`` is (w, x, y, z) = (q0, q1, q2, q3) as
in the paper; ``xyzw`` is ROS's geometry_msgs order. Rotation matrices map model (object)
coordinates to camera coordinates: x_cam = R @ x_model + t. Arrays may carry leading batch
dimensions: quaternions are (..., 4), matrices (..., 3, 3).
"""

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

from bbpose_ros.core.util.errors import InputError


def _bilinear_table(terms):
    """(E, 16): entry e = sum of coefficient * a_i b_j over its (coefficient, i, j) terms."""
    table = np.zeros((len(terms), 4, 4))
    for entry, products in enumerate(terms):
        for coefficient, i, j in products:
            table[entry, i, j] += coefficient
    return table.reshape(len(terms), 16)


def _products_to_matrix():
    """(9, 16): the entries of R (row-major) as linear combinations of q_i q_j, i, j in wxyz."""
    w, x, y, z = range(4)
    return _bilinear_table([
        [(1, w, w), (1, x, x), (-1, y, y), (-1, z, z)], [(2, x, y), (-2, z, w)],
        [(2, x, z), (2, y, w)],
        [(2, x, y), (2, z, w)], [(1, w, w), (-1, x, x), (1, y, y), (-1, z, z)],
        [(2, y, z), (-2, x, w)],
        [(2, x, z), (-2, y, w)], [(2, y, z), (2, x, w)],
        [(1, w, w), (-1, x, x), (-1, y, y), (1, z, z)],
    ])


def _hamilton_product():
    """(4, 16): the entries of p q (wxyz) as linear combinations of p_i q_j, i, j in wxyz."""
    w, x, y, z = range(4)
    return _bilinear_table([
        [(1, w, w), (-1, x, x), (-1, y, y), (-1, z, z)],
        [(1, w, x), (1, x, w), (1, y, z), (-1, z, y)],
        [(1, w, y), (-1, x, z), (1, y, w), (1, z, x)],
        [(1, w, z), (1, x, y), (-1, y, x), (1, z, w)],
    ])


_HAMILTON_PRODUCT = _hamilton_product()

# The homogeneous form of the usual formula (w^2 + x^2 - y^2 - z^2, 2(xy - zw), ...), which
# divides by |q|^2 instead of normalising first: one matrix product for all entries instead
# of building them one by one.
_PRODUCTS_TO_MATRIX = _products_to_matrix()


def quat_wxyz_to_matrix(q_wxyz: npt.ArrayLike) -> np.ndarray:
    """Convert (..., 4) quaternions (w, x, y, z), any non-zero length, to (..., 3, 3)."""
    q = np.asarray(q_wxyz, dtype=float)
    products = (q[..., :, None] * q[..., None, :]).reshape(q.shape[:-1] + (16,))
    entries = (products @ _PRODUCTS_TO_MATRIX.T) / np.sum(q * q, axis=-1, keepdims=True)
    return entries.reshape(q.shape[:-1] + (3, 3))


def quat_multiply(p_wxyz: npt.ArrayLike, q_wxyz: npt.ArrayLike) -> np.ndarray:
    """
    Hamilton products p q of (..., 4) quaternions (w, x, y, z), broadcast: R(p q) = R(p) R(q).

    Lengths multiply, so quaternions of any non-zero length may be composed and converted
    with ``quat_wxyz_to_matrix`` without normalising them first.
    """
    p = np.asarray(p_wxyz, dtype=float)
    products = p[..., :, None] * np.asarray(q_wxyz, dtype=float)[..., None, :]
    return products.reshape(products.shape[:-2] + (16,)) @ _HAMILTON_PRODUCT.T


def matrix_to_quat_wxyz(rotation: npt.ArrayLike) -> np.ndarray:
    """Convert (..., 3, 3) rotation matrices to (..., 4) quaternions (w, x, y, z), w >= 0."""
    rotation = np.asarray(rotation, dtype=float)
    q_xyzw = Rotation.from_matrix(rotation.reshape(-1, 3, 3)).as_quat()
    return positive_hemisphere(xyzw_to_wxyz(q_xyzw)).reshape(rotation.shape[:-2] + (4,))


def wxyz_to_xyzw(q_wxyz: npt.ArrayLike) -> np.ndarray:
    """Reorder (..., 4) quaternions from (w, x, y, z) to ROS's (x, y, z, w)."""
    return np.roll(np.asarray(q_wxyz, dtype=float), -1, axis=-1)


def xyzw_to_wxyz(q_xyzw: npt.ArrayLike) -> np.ndarray:
    """Reorder (..., 4) quaternions from ROS's (x, y, z, w) to (w, x, y, z)."""
    return np.roll(np.asarray(q_xyzw, dtype=float), 1, axis=-1)


def positive_hemisphere(q_wxyz: npt.ArrayLike) -> np.ndarray:
    """
    Apply the paper's q+ rule to (..., 4) quaternions (w, x, y, z): flip q where q0 < 0.

    q and -q are the same rotation; keeping q0 >= 0 gives regression a single target.
    """
    q = np.asarray(q_wxyz, dtype=float)
    return np.where(q[..., :1] < 0.0, -q, q)


def rotation_error_deg(rotation_est: npt.ArrayLike, rotation_gt: npt.ArrayLike) -> np.ndarray:
    """Angle of R_est R_gt^T in degrees (bop_toolkit ``re``); (..., 3, 3) inputs, (...) out."""
    relative = np.asarray(rotation_est) @ np.swapaxes(np.asarray(rotation_gt), -1, -2)
    cos = (np.trace(relative, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def euler_error_deg(rotation_est: npt.ArrayLike, rotation_gt: npt.ArrayLike) -> np.ndarray:
    """
    Compute the paper's Euler error: mean absolute difference of the three angles, degrees.

    Angles are static-axis x-y-z Euler angles; each difference is wrapped to [-180, 180)
    before its absolute value is taken. Inputs (N, 3, 3), output (N,).
    """
    est = Rotation.from_matrix(np.asarray(rotation_est).reshape(-1, 3, 3)).as_euler('xyz')
    gt = Rotation.from_matrix(np.asarray(rotation_gt).reshape(-1, 3, 3)).as_euler('xyz')
    diff = (np.degrees(est - gt) + 180.0) % 360.0 - 180.0
    return np.abs(diff).mean(axis=-1)


def ray_quaternion(rays: npt.ArrayLike) -> np.ndarray:
    """
    Quaternions (N, 4), wxyz, of the rotations that turn the optical axis onto (N, 3) rays.

    This is the view correction between allocentric and egocentric rotation: an object seen
    along ``ray`` with egocentric rotation R_ego looks, in a crop centred on it, like an
    object on the optical axis with allocentric rotation R_allo = V^T R_ego.

    V is the smallest rotation taking z onto the ray r: the turn by the angle a between them
    about n = z x r / |z x r|, whose quaternion (cos a/2, sin a/2 n) is, up to the factor
    2 |r| cos a/2, (|r| + r_z, z x r). That unnormalised form (no trigonometry) is returned:
    ``quat_multiply`` and ``quat_wxyz_to_matrix`` take any length. Rays must point forward
    (r_z > 0), as every camera ray in front of it; they need not be unit.
    """
    rays = np.asarray(rays, dtype=float).reshape(-1, 3)
    q_wxyz = np.zeros((len(rays), 4))
    q_wxyz[:, 0] = np.sqrt((rays * rays).sum(axis=1)) + rays[:, 2]
    q_wxyz[:, 1] = -rays[:, 1]
    q_wxyz[:, 2] = rays[:, 0]
    return q_wxyz


def ray_rotation(rays: npt.ArrayLike) -> np.ndarray:
    """Rotations (N, 3, 3) that turn the optical axis onto (N, 3) rays (``ray_quaternion``)."""
    return quat_wxyz_to_matrix(ray_quaternion(rays))


def allocentric_to_egocentric(rotation_allo: npt.ArrayLike, rays: npt.ArrayLike) -> np.ndarray:
    """Egocentric rotations (N, 3, 3) from allocentric ones seen along (N, 3) camera rays."""
    return ray_rotation(rays) @ np.asarray(rotation_allo, dtype=float).reshape(-1, 3, 3)


def egocentric_to_allocentric(rotation_ego: npt.ArrayLike, rays: npt.ArrayLike) -> np.ndarray:
    """Allocentric rotations (N, 3, 3) from egocentric ones seen along (N, 3) camera rays."""
    views = ray_rotation(rays)
    return np.swapaxes(views, -1, -2) @ np.asarray(rotation_ego, dtype=float).reshape(-1, 3, 3)


def nearest_rotation(matrix: npt.ArrayLike) -> np.ndarray:
    """
    Return the rotation closest (Frobenius norm) to each of (..., 3, 3) near-rotations.

    Stored poses carry rounded digits (BOP's ``cam_R_m2c`` is not quite orthonormal); an
    angle read off the trace of such a matrix can be degrees off near 5 deg, so ground
    truth is projected onto SO(3) when read.
    """
    u, _, vt = np.linalg.svd(np.asarray(matrix, dtype=float))
    flip = np.ones(u.shape[:-1])
    flip[..., -1] = np.sign(np.linalg.det(u @ vt))
    return (u * flip[..., None, :]) @ vt


def exp_so3(rotation_vector: npt.ArrayLike) -> np.ndarray:
    """(..., 3, 3) rotation matrices of (..., 3) rotation vectors (axis times angle, radians)."""
    vector = np.asarray(rotation_vector, dtype=float)
    matrices = Rotation.from_rotvec(vector.reshape(-1, 3)).as_matrix()
    return matrices.reshape(vector.shape[:-1] + (3, 3))


def log_so3(rotation: npt.ArrayLike) -> np.ndarray:
    """(..., 3) rotation vectors (axis times angle, radians, <= pi) of (..., 3, 3) rotations."""
    matrices = np.asarray(rotation, dtype=float)
    vectors = Rotation.from_matrix(matrices.reshape(-1, 3, 3)).as_rotvec()
    return vectors.reshape(matrices.shape[:-2] + (3,))


PERTURB_DIRECTIONS = ('random', 'ray')


def perturb_pose(rotation: npt.ArrayLike, translation: npt.ArrayLike, angle_deg: float,
                 offset_m: float, rng: np.random.Generator,
                 direction: str = 'random') -> tuple[np.ndarray, np.ndarray]:
    """
    Turn a pose by ``angle_deg`` about a random axis, move it ``offset_m`` in a random way.

    The axis is uniform on the sphere; the move is uniform on the sphere (``direction``
    'random') or along the viewing ray through the model origin, towards or away from the
    camera with equal odds ('ray': the error a box of the wrong size gives the Bounding Box
    Equation): the start of a refinement's basin test.

    Returns:
        ((3, 3) rotation, (3,) translation): the rotation error to the given pose is exactly
        ``angle_deg`` and the translation error exactly ``offset_m``.

    """
    if direction not in PERTURB_DIRECTIONS:
        raise InputError(f'perturbation direction must be one of {PERTURB_DIRECTIONS}, got '
                         f'{direction!r}')
    axis, step = rng.normal(size=(2, 3))
    translation = np.asarray(translation, dtype=float)
    if direction == 'ray':
        step = translation * rng.choice((-1.0, 1.0))
    turned = exp_so3(axis / np.linalg.norm(axis) * np.deg2rad(angle_deg)) @ np.asarray(rotation)
    moved = translation + step / np.linalg.norm(step) * offset_m
    return turned, moved
