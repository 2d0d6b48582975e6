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
The Bounding Box Equation: an object's translation from its rotation and its 2D box.

Each side of the 2D box touches the projection of one model point. For the left side at
pixel column u_L, with a = (u_L - cx) / fx and P = R X the rotated touching point,
(P + t)_x / (P + t)_z = a, which is linear in t:

    [1, 0, -a] . t = a P_z - P_x,

and likewise for the right side and, with fy, cy and the y row, for the top and bottom. The
four equations form the paper's 4x3 system A t = b (the paper writes it for the camera
position T = -R^T t; the rows and residuals are the same), solved by least squares. Four
equations for three unknowns: how far the solved pose leaves each touching point from its
side (``TranslationSolution.side_residuals_px``) tells how well the rotation explains the
box's shape, which ``hypotheses`` uses to choose among rotations.

Two ways to choose the touching points (``selection``):

* 'direct_then_perspective': the paper's two steps, then more. Step 1 chooses the touching
  points as the paper's direct conversion does (weak perspective about the box centre: the
  extremes of the rotated points' x and y). Step 2 solves. Then the touching points are
  chosen again under full perspective with the solved t and the system is solved again,
  until the choice stops changing or ``max_iterations`` is reached.
* 'tangent_planes' (default): the plane through the camera centre and the left side's image
  line, x = a z, has the normal n = (1, 0, -a), and the whole object lies on one side of it,
  touching it at the point where n . (P + t) = n . P + n . t is smallest: the point of least
  x - a z among the rotated points, whatever t is. So the touching points come straight from
  the box (one pass, no iteration) and one solve follows. With a box the object fits
  exactly, this is the fixed point the iteration above converges to, reached without the
  iteration's repeated passes.

Everything is batched: N objects, each with M model points (pad smaller sets by repeating a
point, which never changes an extreme; see ``pad_point_sets``).
"""

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

# Order of the four sides in boxes, touching-point indices and side weights.
SIDES = ('left', 'top', 'right', 'bottom')
SELECTIONS = ('tangent_planes', 'direct_then_perspective')
_SIDE_INDEX = np.arange(4)
_SIDE_COORD = np.array([0, 1, 0, 1])     # the coordinate each side bounds: x, y, x, y


@dataclass(frozen=True)
class TranslationSolution:
    """
    What ``solve_translations`` found for N objects.

    Attributes:
        translations: (N, 3) t in metres, camera frame (x_cam = R x_model + t).
        touching: (N, 4) indices of the model points touching the left, top, right and
            bottom sides.
        iterations: (N,) full-perspective re-selections each object needed (0: the direct
            conversion's choice was already right; always 0 with tangent planes).
        converged: (N,) False where ``max_iterations`` ended the re-selection.
        side_residuals_px: (N, 4) signed pixels from the left, top, right and bottom sides
            to the projections of their touching points under the solved pose (u for left
            and right, v for top and bottom); all 0 when the four equations agree, and
            otherwise close to the pose's own box minus the given one (a touching point
            need not stay the extreme one then).

    """

    translations: np.ndarray
    touching: np.ndarray
    iterations: np.ndarray
    converged: np.ndarray
    side_residuals_px: np.ndarray


def pad_point_sets(point_sets: Sequence[np.ndarray]) -> np.ndarray:
    """Stack point sets of different sizes, (M_i, 3) each, into (N, max M_i, 3)."""
    size = max(len(points) for points in point_sets)
    return np.stack([np.concatenate([p, np.repeat(p[-1:], size - len(p), axis=0)])
                     for p in point_sets])


def _extreme_indices(u, v):
    """(N, 4) indices of min u, min v, max u, max v over (N, M) coordinates."""
    return np.stack([u.argmin(axis=1), v.argmin(axis=1), u.argmax(axis=1), v.argmax(axis=1)],
                    axis=1)


def _tangent_indices(rotations, points, boxes_norm):
    """
    (N, 4) indices of the model points touching the planes through the camera and each side.

    Side k's plane has the camera-frame normal n_k = (1, 0, -a) for a left or right side at
    a = (u - cx) / fx, (0, 1, -b) for a top or bottom one; the object touches it where
    n_k . R X is least (left, top) or largest (right, bottom). The normals of the left and
    top sides are flipped so that every side takes a largest value, and they are turned into
    the model frame first (R^T n_k), so one product over the model points does all four.
    """
    normals = np.zeros((len(boxes_norm), 4, 3))
    normals[:, _SIDE_INDEX, _SIDE_COORD] = 1.0
    normals[:, :, 2] = -boxes_norm
    normals[:, :2] *= -1.0
    return np.argmax((normals @ rotations) @ np.swapaxes(points, 1, 2), axis=2)


def _touching_points(rotated, rows, touching):
    """(K, 4, 3) touching points, in side order, of the objects ``rows`` (K,) of (N, 3, M)."""
    return rotated[rows[:, None], :, touching]


class _SideSystems:
    """
    The weighted 4x3 systems A t = b of N objects, solved by the normal equations.

    A and the side weights W depend on the boxes only, so A^T W and A^T W A are made once;
    each re-selection of touching points only changes b.
    """

    def __init__(self, boxes_norm, side_weights):
        a = np.zeros((len(boxes_norm), 4, 3))
        a[:, _SIDE_INDEX, _SIDE_COORD] = 1.0
        a[:, :, 2] = -boxes_norm
        self.boxes_norm = boxes_norm                                    # (N, 4)
        self.aw_t = np.swapaxes(a * side_weights[:, :, None], 1, 2)    # (N, 3, 4): A^T W
        self.normal = self.aw_t @ a                                     # (N, 3, 3): A^T W A

    def solve(self, rows, points):
        """(K, 3) t of the objects ``rows`` (K,) from their (K, 4, 3) touching points R X."""
        b = self.boxes_norm[rows] * points[:, :, 2] - points[:, _SIDE_INDEX, _SIDE_COORD]
        return np.linalg.solve(self.normal[rows], self.aw_t[rows] @ b[:, :, None])[:, :, 0]

    def residuals_px(self, points, translations, fx, fy):
        """(N, 4) pixels from each side to its touching point P + t projected, all objects."""
        moved = points + translations[:, None, :]
        projected = moved[:, _SIDE_INDEX, _SIDE_COORD] / moved[:, :, 2]
        return (projected - self.boxes_norm) * [fx, fy, fx, fy]


def solve_translations(rotations: npt.ArrayLike, boxes_uv: npt.ArrayLike,
                       points: npt.ArrayLike, fx: float, fy: float, cx: float, cy: float,
                       side_weights: npt.ArrayLike | None = None,
                       selection: str = 'tangent_planes',
                       max_iterations: int = 10) -> TranslationSolution:
    """
    Solve the Bounding Box Equation for N objects at once.

    Args:
        rotations: (N, 3, 3) model-to-camera rotations.
        boxes_uv: (N, 4) boxes [u_min, v_min, u_max, v_max] in continuous pixel coordinates
            (pixel centres at integers, see ``CameraIntrinsics``): the outer edges of the
            object's projection.
        points: (N, M, 3) model points in metres (convex-hull points suffice).
        fx, fy, cx, cy: pinhole intrinsics in pixels.
        side_weights: optional (N, 4) weights of the left, top, right and bottom equations,
            e.g. 0 for a side that an image border cut; default all 1. At least one side per
            axis must keep a weight > 0.
        selection: how the touching points are chosen, one of SELECTIONS (module docstring).
        max_iterations: bound on the full-perspective re-selections
            ('direct_then_perspective' only).

    Returns:
        A TranslationSolution.

    """
    rotations = np.asarray(rotations, dtype=float).reshape(-1, 3, 3)
    boxes_uv = np.asarray(boxes_uv, dtype=float).reshape(-1, 4)
    points = np.asarray(points, dtype=float)
    n = len(rotations)
    weights = np.ones((n, 4)) if side_weights is None else np.asarray(side_weights, float)
    boxes_norm = (boxes_uv - [cx, cy, cx, cy]) / [fx, fy, fx, fy]
    systems = _SideSystems(boxes_norm, weights)
    every = np.arange(n)
    iterations = np.zeros(n, dtype=int)
    if selection == 'tangent_planes':
        touching = _tangent_indices(rotations, points, boxes_norm)
        touching_points = np.einsum('nij,nkj->nki', rotations, points[every[:, None], touching])
        translations = systems.solve(every, touching_points)
        return TranslationSolution(translations, touching, iterations, np.ones(n, dtype=bool),
                                   systems.residuals_px(touching_points, translations, fx, fy))
    if selection != 'direct_then_perspective':
        raise ValueError(f'selection must be one of {SELECTIONS}, got {selection!r}')
    # (N, 3, M): R X with each coordinate contiguous over the points, so the per-iteration
    # passes below read whole contiguous rows instead of strided columns of (N, M, 3).
    rotated = rotations @ np.swapaxes(points, 1, 2)
    touching = _extreme_indices(rotated[:, 0], rotated[:, 1])
    translations = systems.solve(every, _touching_points(rotated, every, touching))
    active = np.ones(n, dtype=bool)
    for _ in range(max_iterations):
        idx = np.flatnonzero(active)
        part = rotated if len(idx) == n else rotated[idx]     # no copy while all are active
        t = translations[idx]
        z = part[:, 2] + t[:, 2:]
        in_front = z.min(axis=1) > 0.0
        if not in_front.all():
            z = np.where(z > 0.0, z, 1.0)
        chosen = _extreme_indices((part[:, 0] + t[:, :1]) / z, (part[:, 1] + t[:, 1:2]) / z)
        changed = in_front & np.any(chosen != touching[idx], axis=1)
        active[idx[~changed]] = False
        if not changed.any():
            break
        idx = idx[changed]
        touching[idx] = chosen[changed]
        translations[idx] = systems.solve(idx, _touching_points(rotated, idx, touching[idx]))
        iterations[idx] += 1
    residuals = systems.residuals_px(_touching_points(rotated, every, touching), translations,
                                     fx, fy)
    return TranslationSolution(translations, touching, iterations, ~active, residuals)
