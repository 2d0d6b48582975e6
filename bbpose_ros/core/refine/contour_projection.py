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
Where each pose's contour lies in the image, and which of its points are seen (numba).

* ``closest_views``: the stored view nearest to each pose's camera direction;
* ``project_contours``: the contour points of each pose's closest view, projected, with
  their 2D normals and run lengths in pixels;
* ``hide_occluded``: contour points that another instance's silhouette, nearer the
  camera, covers.

Poses are model-to-camera: x_cam = R @ x_model + t, metres; pixel coordinates are
continuous with pixel centres at integers. Compiled with ``kernel_launch.KERNEL_FLAGS``.
"""

import math

import numba
import numpy as np

from bbpose_ros.core.refine.kernel_launch import KERNEL_FLAGS


@numba.njit(**KERNEL_FLAGS)
def _closest_view(view_directions, rotation, translation):
    """Index of the view direction nearest to the camera's, -R^T t, seen from the model."""
    dx = -(rotation[0, 0] * translation[0] + rotation[1, 0] * translation[1]
           + rotation[2, 0] * translation[2])
    dy = -(rotation[0, 1] * translation[0] + rotation[1, 1] * translation[1]
           + rotation[2, 1] * translation[2])
    dz = -(rotation[0, 2] * translation[0] + rotation[1, 2] * translation[1]
           + rotation[2, 2] * translation[2])
    best, best_dot = 0, -np.inf
    for view in range(view_directions.shape[0]):
        dot = (dx * view_directions[view, 0] + dy * view_directions[view, 1]
               + dz * view_directions[view, 2])
        if dot > best_dot:
            best, best_dot = view, dot
    return best


@numba.njit(**KERNEL_FLAGS)
def closest_views(view_directions, rotations, translations):
    """
    Per pose, the index of the stored view nearest to the camera's direction.

    Args:
        view_directions: (V, 3) unit vectors from the model origin towards the camera.
        rotations: (N, 3, 3) model-to-camera rotations.
        translations: (N, 3) translations (any unit).

    Returns:
        (N,) int64 view indices (the first of equally near ones).

    """
    views = np.empty(rotations.shape[0], dtype=np.int64)
    for n in range(rotations.shape[0]):
        views[n] = _closest_view(view_directions, rotations[n], translations[n])
    return views


@numba.njit(**KERNEL_FLAGS)
def project_contours(view_directions, view_points, view_normals, view_runs_f, view_runs_b,
                     poses, rotation, translation, fx, fy, cx, cy, points, centres, normals,
                     runs_f, runs_b, in_front):
    """
    Project the contour of one object's closest view at each of its poses, into the outputs.

    Args:
        view_directions: (V, 3) the viewpoint model's view directions.
        view_points: (V, P, 3) float32 the viewpoint model's contour points, model frame.
        view_normals: (V, P, 3) float32 their outward normals, model frame.
        view_runs_f: (V, P) float32 how far the silhouette continues inwards, metres.
        view_runs_b: (V, P) float32 how far the background continues outwards, metres.
        poses: (M,) which of the N poses are the object's.
        rotation: (N, 3, 3) model-to-camera rotations of all poses.
        translation: (N, 3) their translations, metres.
        fx: focal length in u, pixels.
        fy: focal length in v, pixels.
        cx: principal point u, pixels.
        cy: principal point v, pixels.
        points: (N, P, 3) float32 out: the views' contour points, model frame.
        centres: (N, P, 2) float64 out: projected (u, v); in front or not.
        normals: (N, P, 2) float64 out: unit 2D normals (u, v).
        runs_f: (N, P) float64 out: the inward run length in pixels at the point's depth.
        runs_b: (N, P) float64 out: the outward one.
        in_front: (N, P) bool out: depth > 1e-6 m.

    """
    lines = view_points.shape[1]
    for m in range(poses.shape[0]):
        n = poses[m]
        r, t = rotation[n], translation[n]
        view = _closest_view(view_directions, r, t)
        for k in range(lines):
            point, normal = view_points[view, k], view_normals[view, k]
            px, py, pz = point[0], point[1], point[2]
            points[n, k, :] = point
            x = r[0, 0] * px + r[0, 1] * py + r[0, 2] * pz + t[0]
            y = r[1, 0] * px + r[1, 1] * py + r[1, 2] * pz + t[1]
            z = r[2, 0] * px + r[2, 1] * py + r[2, 2] * pz + t[2]
            in_front[n, k] = z > 1e-6
            if not z > 1e-6:
                z = 1e-6
            centres[n, k, 0] = fx * x / z + cx
            centres[n, k, 1] = fy * y / z + cy
            nx, ny, nz = normal[0], normal[1], normal[2]
            nu = r[0, 0] * nx + r[0, 1] * ny + r[0, 2] * nz
            nv = r[1, 0] * nx + r[1, 1] * ny + r[1, 2] * nz
            norm = max(math.sqrt(nu * nu + nv * nv), 1e-9)
            normals[n, k, 0], normals[n, k, 1] = nu / norm, nv / norm
            px_per_m = fx / z
            runs_f[n, k] = view_runs_f[view, k] * px_per_m
            runs_b[n, k] = view_runs_b[view, k] * px_per_m


# Horizontal bands an occluder's outline is cut into: a point's inside test reads only the
# edges that cross its band.
OUTLINE_BANDS = 64


@numba.njit(**KERNEL_FLAGS)
def _outline_bands(polygon, v_low, per_band, bands):
    """
    Index a closed (P, 2) outline's edges by the horizontal bands of rows they span.

    A row v lies in band min(int((v - v_low) * per_band), bands - 1), the expression
    ``hide_occluded`` places its points by; edge i joins vertex i - 1 (the last for i = 0)
    to vertex i and is listed in the bands of its two ends' rows and those between. An edge
    a point crosses (min(v_i, v_j) <= v < max(v_i, v_j)) is therefore listed in the point's
    band: the expression never reverses the order of two rows.

    Returns:
        ((bands + 1,) int64 starts, (E,) int64 edges): band b's edges are
        ``edges[starts[b]:starts[b + 1]]``.

    """
    points = polygon.shape[0]
    first, last = np.empty(points, dtype=np.int64), np.empty(points, dtype=np.int64)
    starts = np.zeros(bands + 1, dtype=np.int64)
    previous = points - 1
    for i in range(points):
        v_i, v_j = polygon[i, 1], polygon[previous, 1]
        first[i] = min(int((min(v_i, v_j) - v_low) * per_band), bands - 1)
        last[i] = min(int((max(v_i, v_j) - v_low) * per_band), bands - 1)
        for b in range(first[i], last[i] + 1):
            starts[b + 1] += 1
        previous = i
    for b in range(bands):
        starts[b + 1] += starts[b]
    edges = np.empty(starts[bands], dtype=np.int64)
    fill = starts[:bands].copy()
    for i in range(points):
        for b in range(first[i], last[i] + 1):
            edges[fill[b]] = i
            fill[b] += 1
    return starts, edges


@numba.njit(**KERNEL_FLAGS)
def _inside_outline(u, v, polygon, band, starts, edges):
    """Tell whether (u, v) lies inside an outline (even-odd rule), by its band's edges."""
    inside = False
    points = polygon.shape[0]
    for e in range(starts[band], starts[band + 1]):
        i = edges[e]
        j = i - 1 if i > 0 else points - 1
        u_i, v_i, u_j, v_j = polygon[i, 0], polygon[i, 1], polygon[j, 0], polygon[j, 1]
        if (v_i > v) != (v_j > v) and u < (u_j - u_i) * (v - v_i) / (v_j - v_i) + u_i:
            inside = not inside
    return inside


@numba.njit(**KERNEL_FLAGS)
def hide_occluded(centres, depths, instances, casts, in_front):
    """
    Mark the contour points that a nearer instance's silhouette covers as not seen.

    A pose's projected contour, in the order it was traced, is its silhouette's outline;
    where a pose of another instance, nearer the camera by its origin's depth, covers a
    contour point of this one, the image shows the occluder there, not this contour.

    Args:
        centres: (N, P, 2) projected contour points, pixels, in outline order.
        depths: (N,) depth of each pose's model origin, metres.
        instances: (N,) int the instance each pose is a candidate for: poses of the same
            instance are alternatives and never hide each other.
        casts: (N,) bool which poses hide others (e.g. one candidate per instance).
        in_front: (N, P) bool contour points seen, updated in place.

    """
    count, points = in_front.shape
    for m in range(count):
        if not casts[m]:
            continue
        u_low, u_high = centres[m, :, 0].min(), centres[m, :, 0].max()
        v_low, v_high = centres[m, :, 1].min(), centres[m, :, 1].max()
        per_band = OUTLINE_BANDS / (v_high - v_low)
        if not (v_high > v_low and math.isfinite(u_low + u_high + v_low + v_high)
                and math.isfinite(per_band)):
            continue        # no area, or not finite: it covers nothing
        starts, edges = _outline_bands(centres[m], v_low, per_band, OUTLINE_BANDS)
        for n in range(count):
            if instances[m] == instances[n] or depths[m] >= depths[n]:
                continue
            for k in range(points):
                u, v = centres[n, k, 0], centres[n, k, 1]
                if in_front[n, k] and u_low <= u <= u_high and v_low <= v <= v_high:
                    band = min(int((v - v_low) * per_band), OUTLINE_BANDS - 1)
                    if _inside_outline(u, v, centres[m], band, starts, edges):
                        in_front[n, k] = False
