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
Object models: BOP meshes in metres, their size, 3D box, symmetries and solver points.

BOP meshes and ``models_info.json`` are in millimetres; everything here is converted to
metres once, at load time.

Objects are known by name. A dataset names its objects in ``models/models_names.json``,
``{"<obj_id>": "<name>"}`` for every object of ``models_info.json`` (names: a letter, then
letters, digits or '_', as they become ROS topic names ``~/<name>/pose``). A dataset
without that table gets LineMod's names by BOP id (``LINEMOD_OBJECTS``, as LM-O needs),
``obj_NNNNNN`` for other ids. ``object_names`` is the one reader of the names.
"""

from collections.abc import Collection, Iterable, Mapping
from dataclasses import dataclass, field
import json
from pathlib import Path
import re
from typing import Any

import numpy as np
import numpy.typing as npt
import trimesh

from bbpose_ros.core.util.errors import InputError

MM_TO_M = 1e-3

# BOP object ids of the LineMod family (LM and LM-O share them).
LINEMOD_OBJECTS = {
    1: 'ape', 2: 'benchvise', 3: 'bowl', 4: 'camera', 5: 'can', 6: 'cat', 7: 'cup',
    8: 'driller', 9: 'duck', 10: 'eggbox', 11: 'glue', 12: 'holepuncher', 13: 'iron',
    14: 'lamp', 15: 'phone',
}
# The eight objects annotated in LineMod-Occluded (BOP ids 1, 5, 6, 8, 9, 10, 11, 12).
LMO_OBJECTS = tuple(LINEMOD_OBJECTS[obj_id] for obj_id in (1, 5, 6, 8, 9, 10, 11, 12))
# A dataset's table of object names, in its models/ folder: {"<obj_id>": "<name>"}.
NAMES_FILE = 'models_names.json'
# An object name: it becomes a ROS name (~/<name>/pose), so a letter, then [A-Za-z0-9_].
_NAME_PATTERN = re.compile(r'[A-Za-z][A-Za-z0-9_]*')


@dataclass
class ObjectModel:
    """
    One rigid object, in metres, in its model frame.

    Attributes:
        name: object name, e.g. 'ape'.
        obj_id: BOP object id.
        vertices: (V, 3) mesh vertices.
        faces: (F, 3) vertex indices of the triangles.
        vertex_colors: (V, 3) uint8 RGB colours (grey when the mesh has none).
        diameter: largest distance between two model points (from models_info.json).
        hull_points: (H, 3) convex-hull vertices; a perspective projection's extreme points
            always lie among them, so the Bounding Box Equation needs only these.
        eval_points: (P, 3) points for the pose metrics (BOP's models_eval when present).
        symmetries: (S, 4, 4) discrete symmetry transforms (translation in metres), identity
            excluded; empty for objects without symmetry.

    """

    name: str
    obj_id: int
    vertices: np.ndarray
    faces: np.ndarray
    vertex_colors: np.ndarray
    diameter: float
    hull_points: np.ndarray
    eval_points: np.ndarray
    symmetries: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4)))

    @property
    def is_symmetric(self) -> bool:
        """Tell whether the object has symmetry transforms (then ADD-S is its metric)."""
        return len(self.symmetries) > 0

    @property
    def box_corners(self) -> np.ndarray:
        """(8, 3) corners of the axis-aligned 3D box of the vertices, in a fixed order."""
        lo, hi = self.vertices.min(axis=0), self.vertices.max(axis=0)
        bits = np.array([[i >> 2 & 1, i >> 1 & 1, i & 1] for i in range(8)], dtype=float)
        return lo + bits * (hi - lo)

    @property
    def symmetry_transforms(self) -> np.ndarray:
        """(S + 1, 4, 4) all pose-equivalent transforms, identity first."""
        return np.concatenate([np.eye(4)[None], self.symmetries], axis=0)


# The 12 edges of ``ObjectModel.box_corners``, as index pairs (corners differ in one bit).
BOX_EDGES = np.array([(i, i | 1 << b) for i in range(8) for b in range(3) if not i >> b & 1])


def read_mesh_file(path: Path | str) -> trimesh.Trimesh:
    """Read a mesh file, unprocessed; a missing, broken or empty file is an InputError."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f'mesh file not found: {path}')
    try:
        mesh = trimesh.load(path, process=False, force='mesh')
    except Exception as err:  # trimesh raises many types for a broken file
        raise InputError(f'cannot read mesh {path}: {err}') from err
    if len(mesh.vertices) < 4 or len(mesh.faces) == 0:
        raise InputError(f'mesh {path} is empty ({len(mesh.vertices)} vertices, '
                         f'{len(mesh.faces)} faces)')
    return mesh


def load_mesh(path: Path | str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Load a PLY mesh (millimetres) as (vertices_m, faces, colours); errors name the file."""
    mesh = read_mesh_file(path)
    vertices = np.asarray(mesh.vertices, dtype=np.float64) * MM_TO_M
    colors = getattr(mesh.visual, 'vertex_colors', None)
    if colors is None or len(colors) != len(vertices):
        colors = np.full((len(vertices), 3), 128, dtype=np.uint8)
    return vertices, np.asarray(mesh.faces, dtype=np.int64), np.asarray(colors)[:, :3].copy()


def load_models_info(path: Path | str) -> dict[int, dict[str, Any]]:
    """Read BOP ``models_info.json`` into {obj_id: dict}; errors name the file."""
    path = Path(path)
    try:
        info = json.loads(path.read_text())
        return {int(k): v for k, v in info.items()}
    except FileNotFoundError as err:
        raise InputError(f'models info not found: {path}') from err
    except (ValueError, AttributeError) as err:
        raise InputError(f'malformed JSON in {path}: {err}') from err


def convex_hull_points(vertices: npt.ArrayLike) -> np.ndarray:
    """(H, 3) vertices of the convex hull of (V, 3) points."""
    return np.asarray(trimesh.convex.convex_hull(vertices).vertices, dtype=np.float64)


def symmetry_matrices(info: Mapping[str, Any]) -> np.ndarray:
    """(S, 4, 4) symmetry transforms in metres from one models_info entry (discrete only)."""
    syms = np.asarray(info.get('symmetries_discrete', []), dtype=float).reshape(-1, 4, 4)
    syms[:, :3, 3] *= MM_TO_M
    return syms


def load_object_model(models_dir: Path | str, obj_id: int, info: Mapping[str, Any],
                      name: str, eval_dir: Path | str | None = None) -> ObjectModel:
    """Load one BOP object: its mesh from ``models_dir`` and metric points from ``eval_dir``."""
    filename = f'obj_{obj_id:06d}.ply'
    vertices, faces, colors = load_mesh(Path(models_dir) / filename)
    eval_path = Path(eval_dir) / filename if eval_dir is not None else None
    eval_points = load_mesh(eval_path)[0] if eval_path and eval_path.is_file() else vertices
    try:
        diameter = float(info['diameter']) * MM_TO_M
    except (KeyError, TypeError, ValueError) as err:
        raise InputError(f'models_info entry of object {obj_id} has no valid diameter') from err
    return ObjectModel(
        name=name, obj_id=obj_id,
        vertices=vertices, faces=faces, vertex_colors=colors, diameter=diameter,
        hull_points=convex_hull_points(vertices), eval_points=eval_points,
        symmetries=symmetry_matrices(info))


def resolve_object_names(requested: Collection[str] | None, available: Iterable[str],
                         source: str = '') -> list[str]:
    """
    Check requested object names against the available ones and keep the dataset's order.

    ``requested`` None or empty means all. An unknown name is an InputError naming it, the
    names' ``source`` (``names_source``) when given, and the known names.
    """
    available = list(available)
    if not requested:
        return available
    unknown = [name for name in requested if name not in available]
    if unknown:
        where = f' in {source}' if source else ''
        raise InputError(f'unknown object name(s) {", ".join(unknown)}{where}; '
                         f'known: {", ".join(available)}')
    return [name for name in available if name in set(requested)]


def fallback_object_name(obj_id: int) -> str:
    """Return the name of an object a dataset has no names table for: LineMod's, else obj_N."""
    return LINEMOD_OBJECTS.get(obj_id, f'obj_{obj_id:06d}')


def check_names(names: Mapping[int, Any], where: str) -> None:
    """
    Raise InputError, naming ``where``, unless {obj_id: name} are valid, distinct names.

    A valid name is a letter, then letters, digits or '_' (names become ROS topic names).
    """
    bad = [repr(name) for name in names.values()
           if not isinstance(name, str) or not _NAME_PATTERN.fullmatch(name)]
    if bad:
        raise InputError(f'{where}: invalid object name(s) {", ".join(bad)} (a letter, then '
                         'letters, digits or _: names become ROS topic names)')
    values = list(names.values())
    repeated = sorted({name for name in values if values.count(name) > 1})
    if repeated:
        raise InputError(f'{where}: name(s) {", ".join(repeated)} given to several ids')


def object_names(dataset_dir: Path | str) -> dict[int, str]:
    """
    Return {obj_id: name} of a dataset's objects, in object-id order.

    Names come from ``models/models_names.json`` when the dataset has it (it must name
    every object of ``models_info.json``, and nothing else), else ``fallback_object_name``
    of each id of ``models_info.json``; a dataset without ``models_info.json`` has none.
    Errors name the file and the offending ids or names.
    """
    models_dir = Path(dataset_dir) / 'models'
    info_path = models_dir / 'models_info.json'
    table_path = models_dir / NAMES_FILE
    if not table_path.is_file():
        ids = sorted(load_models_info(info_path)) if info_path.is_file() else []
        return {obj_id: fallback_object_name(obj_id) for obj_id in ids}
    try:
        table = json.loads(table_path.read_text())
        names = {int(key): value for key, value in table.items()}
    except (ValueError, AttributeError) as err:
        raise InputError(f'{table_path}: expected a JSON object {{"<obj_id>": "<name>"}} '
                         f'({err})') from err
    check_names(names, str(table_path))
    ids = set(load_models_info(info_path))
    for what, wrong in (('not in models_info.json', sorted(set(names) - ids)),
                        ('of models_info.json without a name', sorted(ids - set(names)))):
        if wrong:
            raise InputError(f'{table_path}: object id(s) {", ".join(map(str, wrong))} {what} '
                             f'(ids of {info_path}: {", ".join(map(str, sorted(ids)))})')
    return dict(sorted(names.items()))


def names_source(dataset_dir: Path | str) -> str:
    """Say where a dataset's object names come from (for error messages)."""
    table_path = Path(dataset_dir) / 'models' / NAMES_FILE
    if table_path.is_file():
        return str(table_path)
    return (f"{Path(dataset_dir) / 'models'} (LineMod's names by BOP id: no {NAMES_FILE})")


def bop_object_ids(dataset_dir: Path | str) -> dict[str, int]:
    """Return {name: BOP object id} of a dataset's objects (see ``object_names``)."""
    return {name: obj_id for obj_id, name in object_names(dataset_dir).items()}


def load_bop_models(dataset_dir: Path | str,
                    names: Collection[str] | None = None) -> dict[str, ObjectModel]:
    """
    Load the objects of a BOP dataset folder as {name: ObjectModel}, in object-id order.

    Reads ``models/`` (meshes, models_info.json, the names table) and, when present,
    ``models_eval/``. ``names`` restricts the set; unknown names are an InputError.
    """
    dataset_dir = Path(dataset_dir)
    models_dir = dataset_dir / 'models'
    info = load_models_info(models_dir / 'models_info.json')
    ids_by_name = bop_object_ids(dataset_dir)
    eval_dir = dataset_dir / 'models_eval'
    return {
        name: load_object_model(models_dir, ids_by_name[name], info[ids_by_name[name]], name,
                                eval_dir if eval_dir.is_dir() else None)
        for name in resolve_object_names(names, ids_by_name, names_source(dataset_dir))
    }
