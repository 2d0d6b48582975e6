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
The pull of each pose's correspondence lines on its pose: gradient and Hessian (numba).

``gradient_hessian`` sums, over each pose's valid lines, the Gauss-Newton gradient and
Hessian of the lines' residuals (the contour distribution's mean against the projected
point's offset on its line) over the 6-DoF increment in the model frame;
``optimizer.newton_update`` solves for the step.
"""

import numba
import numpy as np

from bbpose_ros.core.refine.kernel_launch import KERNEL_FLAGS


@numba.njit(**KERNEL_FLAGS)
def gradient_hessian(rotation, translation, points_model, centres, normals, valid, mean,
                     variance, scale, weight_scale, fx, fy, cx, cy):
    """
    Each pose's pull from its lines: (N, 6) gradient, (N, 6, 6) Gauss-Newton Hessian.

    Args:
        rotation: (N, 3, 3) model-to-camera rotations.
        translation: (N, 3) translations, metres.
        points_model: (N, P, 3) contour points, model frame, metres.
        centres: (N, P, 2) projected contour points when the lines were made.
        normals: (N, P, 2) unit outward normals of the lines.
        valid: (N, P) bool lines that count.
        mean: (N, P) the contour distributions' means, segments.
        variance: (N, P) their variances, segments squared.
        scale: pixels per segment.
        weight_scale: a line's weight is weight_scale / variance.
        fx: focal length in u, pixels.
        fy: focal length in v, pixels.
        cx: principal point u, pixels.
        cy: principal point v, pixels.

    Over the increment (rotation vector, translation, both in the model frame), each
    valid line's projected point moves along its normal by J . theta segments; its residual
    is mean - (its offset from the centre, in segments).

    """
    count, lines = points_model.shape[0], points_model.shape[1]
    gradient = np.zeros((count, 6))
    hessian = np.zeros((count, 6, 6))
    jacobian = np.empty(6)
    for n in range(count):
        r = rotation[n]
        for k in range(lines):
            if not valid[n, k]:
                continue
            px, py, pz = points_model[n, k, 0], points_model[n, k, 1], points_model[n, k, 2]
            x = r[0, 0] * px + r[0, 1] * py + r[0, 2] * pz + translation[n, 0]
            y = r[1, 0] * px + r[1, 1] * py + r[1, 2] * pz + translation[n, 1]
            z = r[2, 0] * px + r[2, 1] * py + r[2, 2] * pz + translation[n, 2]
            if abs(z) <= 1e-6:
                z = 1e-6
            fx_z, fy_z = fx / z, fy / z
            n_u, n_v = normals[n, k, 0], normals[n, k, 1]
            delta = (n_u * (x * fx_z + cx - centres[n, k, 0])
                     + n_v * (y * fy_z + cy - centres[n, k, 1])) / scale
            d_x, d_y = n_u * fx_z / scale, n_v * fy_z / scale
            d_z = -(n_u * x * fx_z + n_v * y * fy_z) / z / scale
            # The camera-frame derivative turned into the model frame: d @ R.
            t_x = d_x * r[0, 0] + d_y * r[1, 0] + d_z * r[2, 0]
            t_y = d_x * r[0, 1] + d_y * r[1, 1] + d_z * r[2, 1]
            t_z = d_x * r[0, 2] + d_y * r[1, 2] + d_z * r[2, 2]
            jacobian[0] = py * t_z - pz * t_y
            jacobian[1] = pz * t_x - px * t_z
            jacobian[2] = px * t_y - py * t_x
            jacobian[3], jacobian[4], jacobian[5] = t_x, t_y, t_z
            weight = weight_scale / variance[n, k]
            residual = (mean[n, k] - delta) * weight
            for a in range(6):
                gradient[n, a] += residual * jacobian[a]
                wa = weight * jacobian[a]
                for b in range(a, 6):
                    hessian[n, a, b] += wa * jacobian[b]
        for a in range(6):
            for b in range(a):
                hessian[n, a, b] = hessian[n, b, a]
    return gradient, hessian
