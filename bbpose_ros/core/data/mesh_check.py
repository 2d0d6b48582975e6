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
Checking a new object's mesh and turning it into a BOP model (``bbpose check-mesh``).

A mesh from a CAD tool or a scanner may be in metres or millimetres, without colours, open
or huge. ``check_mesh`` reads it (any format trimesh reads: PLY, OBJ, STL, GLB; a texture
becomes vertex colours) and finds:

- problems that refuse it: units that contradict the size (a diameter that is plausible
  only in the other unit), a size outside ``DIAMETER_RANGE_M`` for a tabletop object, no
  vertex colours and no uniform colour given;
- notes that do not: open edges (not watertight: the renders show the holes), edges of
  more than two faces, an origin far from the mesh, a mesh of more than ``max_faces``
  faces (decimated by vertex clustering, ``cluster_vertices``).

``write_bop_model`` writes what the BOP format needs of the checked mesh: the PLY in
millimetres with vertex colours, and its ``models_info.json`` entry (``diameter``, the
box fields ``min_x`` .. ``size_z``, millimetres). The pipeline reads ``diameter`` and,
for symmetric objects, ``symmetries_discrete`` (4x4 row-major, translation in mm), which
no mesh check can find: add it by hand.
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from bbpose_ros.core.data.models import (check_names, convex_hull_points, MM_TO_M, NAMES_FILE,
                                         read_mesh_file)
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.core.util.files import atomic_output, write_json_atomic

# Metres per file unit.
UNITS = {'mm': MM_TO_M, 'm': 1.0}
# Diameters (metres) plausible for an object on a table: 1 cm to 1 m. The range spans a
# factor of 100, less than mm / m, so a wrong unit always leaves it.
DIAMETER_RANGE_M = (0.01, 1.0)
# More faces than this are decimated: LM-O's meshes have 12k-46k, and every face costs
# rendering time in training and in the refiner.
MAX_FACES = 50_000
# Vertex-clustering cell sizes tried, as fractions of the diameter (bisection bounds).
_CELL_RANGE = (1e-4, 0.25)
_CELL_STEPS = 24


@dataclass(frozen=True)
class CheckedMesh:
    """
    A mesh as checked, in metres, ready for ``write_bop_model``.

    Attributes:
        path: the file read.
        vertices: (V, 3) float64 vertices, metres (the declared units converted).
        faces: (F, 3) int64 vertex indices.
        colors: (V, 3) uint8 RGB vertex colours (the uniform colour given, if any).
        diameter_m: largest distance between two vertices, metres.
        open_edges: edges of exactly one face (0: watertight).
        notes: what is worth knowing but refuses nothing (decimation, open edges, ...).

    """

    path: Path
    vertices: np.ndarray
    faces: np.ndarray
    colors: np.ndarray
    diameter_m: float
    open_edges: int
    notes: tuple[str, ...]

    def models_info_entry(self) -> dict[str, float]:
        """Return the BOP ``models_info.json`` entry: diameter and box, millimetres."""
        lo, hi = self.vertices.min(axis=0) / MM_TO_M, self.vertices.max(axis=0) / MM_TO_M
        return {'diameter': round(self.diameter_m / MM_TO_M, 4),
                **{f'min_{axis}': round(float(low), 4) for axis, low in zip('xyz', lo)},
                **{f'size_{axis}': round(float(size), 4) for axis, size in zip('xyz', hi - lo)}}


def check_mesh(path: Path | str, units: str = 'mm',
               color: tuple[int, int, int] | None = None,
               max_faces: int = MAX_FACES) -> CheckedMesh:
    """
    Read and check a new object's mesh (see the module docstring).

    Args:
        path: the mesh file.
        units: the file's length unit, 'mm' (BOP's) or 'm'.
        color: (R, G, B) 0-255 to paint the whole mesh with; None keeps its colours.
        max_faces: meshes with more faces are decimated to at most this many.

    Raises:
        InputError: naming the file and every problem found (units, size, colours), or
            an unreadable or empty file.

    """
    path = Path(path)
    if units not in UNITS:
        raise InputError(f'units must be one of {", ".join(UNITS)}, got {units!r}')
    if max_faces < 4:
        raise InputError(f'max_faces must be at least 4, got {max_faces}')
    mesh = read_mesh_file(path)
    raw = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    diameter = max_distance(raw)
    problems = _size_problems(diameter, units)
    colors = _vertex_colors(mesh)
    if color is not None:
        colors = np.tile(np.asarray(color, dtype=np.uint8), (len(raw), 1))
    elif colors is None:
        problems.append('no vertex colours (nor a texture): give a uniform colour '
                        '(--color R,G,B)')
    if problems:
        raise InputError(f'mesh {path}: ' + '; '.join(problems))
    vertices = raw * UNITS[units]
    diameter_m = diameter * UNITS[units]
    notes = []
    if len(faces) > max_faces:
        count = len(faces)
        vertices, faces, colors = decimate(vertices, faces, colors, max_faces, diameter_m)
        diameter_m = max_distance(vertices)
        notes.append(f'{count} faces: decimated to {len(faces)} (at most {max_faces}) by '
                     'vertex clustering')
    open_edges, shared_edges = edge_counts(faces)
    if open_edges:
        notes.append(f'not watertight: {open_edges} open edges (the renders show the holes; '
                     'close them in a mesh editor if they are not in the real object)')
    if shared_edges:
        notes.append(f'{shared_edges} edges of more than two faces (non-manifold)')
    offset = np.linalg.norm((vertices.min(axis=0) + vertices.max(axis=0)) / 2)
    if offset > diameter_m:
        notes.append(f'the origin is {offset:.3f} m from the box centre (diameter '
                     f'{diameter_m:.3f} m): poses are reported of this origin')
    return CheckedMesh(path, vertices, faces, colors, diameter_m, open_edges, tuple(notes))


def _size_problems(diameter, units):
    """Return what is wrong with a diameter (file units) in the declared ``units``."""
    low, high = DIAMETER_RANGE_M
    metres = {name: diameter * scale for name, scale in UNITS.items()}
    if low <= metres[units] <= high:
        return []
    plausible = [name for name, value in metres.items() if low <= value <= high]
    size = (f'diameter {diameter:.4g} (file units) is {metres[units]:.4g} m as {units}, '
            f'outside {low:g}-{high:g} m for a tabletop object')
    if plausible:
        other = plausible[0]
        return [f'units: {size}; as {other} it is {metres[other]:.4g} m: the file looks like '
                f'{other}, not {units} (--units {other}, or scale the mesh)']
    return [f'size: {size}']


def _vertex_colors(mesh):
    """(V, 3) uint8 colours of a mesh's vertices (a texture sampled), or None without any."""
    visual = mesh.visual
    if visual.kind == 'texture':
        visual = visual.to_color()
    if visual.kind not in ('vertex', 'face'):
        return None
    return np.asarray(visual.vertex_colors)[:, :3].astype(np.uint8)


def max_distance(points: np.ndarray) -> float:
    """Return the largest distance between two of (N, 3) points (over their convex hull)."""
    try:
        hull = convex_hull_points(points)
    except Exception:  # flat or degenerate point sets have no 3D hull: use them all
        hull = np.unique(points, axis=0)
    best = 0.0
    for start in range(0, len(hull), 1024):
        block = hull[start:start + 1024]
        distances = np.linalg.norm(block[:, None, :] - hull[None, :, :], axis=2)
        best = max(best, float(distances.max()))
    return best


def edge_counts(faces: np.ndarray) -> tuple[int, int]:
    """Return (open, non-manifold) edge counts of (F, 3) triangles: edges of 1, >2 faces."""
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return int(np.count_nonzero(counts == 1)), int(np.count_nonzero(counts > 2))


def cluster_vertices(vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray,
                     cell: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Merge the vertices of each cube of side ``cell`` (metres) into their mean.

    Faces whose corners merge are dropped, and so are repeated ones; colours are averaged
    like the positions. Returns (vertices, faces, colors) of the coarser mesh.
    """
    cells = np.floor((vertices - vertices.min(axis=0)) / cell).astype(np.int64)
    span = cells.max(axis=0) + 1
    keys = (cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2]
    _, inverse = np.unique(keys, return_inverse=True)
    inverse = inverse.reshape(-1)
    counts = np.bincount(inverse)[:, None]
    merged = np.stack([np.bincount(inverse, weights=vertices[:, k]) for k in range(3)], 1)
    mixed = np.stack([np.bincount(inverse, weights=colors[:, k]) for k in range(3)], 1)
    new_faces = inverse[faces]
    distinct = ((new_faces[:, 0] != new_faces[:, 1]) & (new_faces[:, 1] != new_faces[:, 2])
                & (new_faces[:, 2] != new_faces[:, 0]))
    new_faces = new_faces[distinct]
    _, first = np.unique(np.sort(new_faces, axis=1), axis=0, return_index=True)
    new_faces = new_faces[np.sort(first)]
    used, compact = np.unique(new_faces, return_inverse=True)
    return ((merged / counts)[used], compact.reshape(-1, 3),
            np.round(mixed / counts).astype(np.uint8)[used])


def decimate(vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray, max_faces: int,
             diameter: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Return the finest ``cluster_vertices`` mesh with at most ``max_faces`` faces.

    The cell size is bisected (geometrically) between ``_CELL_RANGE`` x ``diameter``.
    """
    low, high = (fraction * diameter for fraction in _CELL_RANGE)
    best = cluster_vertices(vertices, faces, colors, high)
    for _ in range(_CELL_STEPS):
        cell = np.sqrt(low * high)
        candidate = cluster_vertices(vertices, faces, colors, cell)
        if len(candidate[1]) <= max_faces:
            best, high = candidate, cell
        else:
            low = cell
    return best


def write_bop_model(checked: CheckedMesh, out: Path | str, obj_id: int, name: str) -> None:
    """
    Write a BOP ``models/`` folder of one object at ``out`` (which must not exist yet).

    It holds ``obj_NNNNNN.ply`` (millimetres, vertex colours), ``models_info.json`` with
    the object's entry and the names table ``models_names.json`` {obj_id: name}; the folder
    appears complete or not at all. The name must pass ``check_names``.
    """
    out = Path(out)
    check_names({obj_id: name}, 'the object name')
    if out.exists():
        raise InputError(f'output folder already exists: {out} (choose a new one)')
    if obj_id < 1:
        raise InputError(f'the object id must be a positive integer, got {obj_id}')
    mesh = trimesh.Trimesh(checked.vertices / MM_TO_M, checked.faces,
                           vertex_colors=checked.colors, process=False)
    with atomic_output(out) as staging:
        staging.mkdir()
        mesh.export(staging / f'obj_{obj_id:06d}.ply', file_type='ply')
        write_json_atomic(staging / 'models_info.json',
                          {str(obj_id): checked.models_info_entry()})
        write_json_atomic(staging / NAMES_FILE, {str(obj_id): name})
