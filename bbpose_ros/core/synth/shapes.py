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

"""Random coloured primitive meshes (boxes, cylinders, ellipsoids...) used as distractors."""

from collections.abc import Sequence

import numpy as np
import trimesh

from bbpose_ros.core.render.mesh import RenderMesh


def _primitive(rng, size):
    """Make a random primitive about ``size`` metres across, as a trimesh.Trimesh."""
    kind = rng.integers(5)
    half = size / 2.0
    if kind == 0:
        mesh = trimesh.creation.box(extents=rng.uniform(0.3, 1.0, 3) * size)
        mesh = mesh.subdivide().subdivide()
        mesh.unmerge_vertices()  # flat shading: no normals shared across the box edges
    elif kind == 1:
        mesh = trimesh.creation.cylinder(radius=half * rng.uniform(0.2, 1.0), height=size,
                                         sections=24)
    elif kind == 2:
        mesh = trimesh.creation.icosphere(subdivisions=2, radius=half)
        mesh.apply_scale(rng.uniform(0.3, 1.0, 3))
    elif kind == 3:
        mesh = trimesh.creation.capsule(height=size * rng.uniform(0.3, 0.7),
                                        radius=half * rng.uniform(0.2, 0.5), count=[16, 16])
    else:
        mesh = trimesh.creation.cone(radius=half * rng.uniform(0.3, 1.0), height=size,
                                     sections=24)
    mesh.apply_translation(-mesh.bounds.mean(axis=0))
    return mesh


def _colors(rng, vertices):
    """Pick (V, 3) uint8 vertex colours: one plain colour or stripes of two, plus noise."""
    base = rng.uniform(0, 255, (2, 3))
    if rng.random() < 0.5:
        direction = rng.normal(size=3)
        period = rng.uniform(0.01, 0.05)
        phase = vertices @ (direction / np.linalg.norm(direction)) / period
        weight = (np.sin(phase) > 0.0)[:, None].astype(float)
    else:
        weight = np.zeros((len(vertices), 1))
    colors = base[0] * (1.0 - weight) + base[1] * weight
    colors += rng.normal(0.0, 8.0, colors.shape)
    return np.clip(colors, 0, 255).astype(np.uint8)


def random_shape(rng: np.random.Generator, size_range: Sequence[float]) -> RenderMesh:
    """Make a random primitive ``RenderMesh``, ``size_range`` (low, high) metres across."""
    mesh = _primitive(rng, rng.uniform(*size_range))
    vertices = np.asarray(mesh.vertices, dtype=float)
    return RenderMesh.from_arrays(vertices, np.asarray(mesh.faces), _colors(rng, vertices))
