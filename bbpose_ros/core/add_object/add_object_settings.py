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
What ``bbpose add-object`` is given: the object, and how much to render and train.

The object is its name, checked mesh and symmetries (``AddedObject``); the renders and
training are ``AddObjectSettings``, declared as every setting is (``util.declarations``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from bbpose_ros.core.data.models import MM_TO_M
from bbpose_ros.core.training.cache import SHARD_SIZE
from bbpose_ros.core.training.crop_cache import SHARD_SIZE as CROP_SHARD_SIZE
from bbpose_ros.core.training.settings import RowTraining
from bbpose_ros.core.util.declarations import check_settings, nested, setting
from bbpose_ros.core.util.errors import InputError

if TYPE_CHECKING:
    from bbpose_ros.core.data.mesh_check import CheckedMesh


@dataclass(frozen=True)
class AddObjectSettings:
    """
    How much to render and train (recorded in ``report.json``).

    Besides its settings, the RowTraining of each network: ``detector`` (its heatmap
    channel), ``qnet`` (its head) and ``dense`` (its output channels).

    Raises:
        InputError: 'name: reason' for the first value it does not take.

    """

    scenes: int = setting(500, 'Table-top scenes rendered for the detector.', low=1)
    crops: int = setting(8000, 'Crops rendered for Q-Net and the dense net.', low=1)
    detector: RowTraining = nested(lambda: RowTraining(steps=1000, passes=2))
    qnet: RowTraining = nested(lambda: RowTraining(steps=2000, passes=3, seeds=3))
    dense: RowTraining = nested(lambda: RowTraining(steps=1500, passes=1))
    seed: int = setting(101, 'Seed of the renders and draws.')
    workers: int = setting(2, 'Rendering processes.', low=1)
    scene_shard: int = setting(
        SHARD_SIZE, 'Scenes per cache shard (renders resume shard by shard).', low=1)
    crop_shard: int = setting(CROP_SHARD_SIZE, 'Crops per cache shard.', low=1)
    held_out: float = setting(
        0.1, 'Share of the renders kept for the figures in report.json.', low=0.0, high=1.0)

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass(frozen=True)
class AddedObject:
    """
    The object to add.

    Attributes:
        name: its name (topics ``~/<name>/pose``, the ``objects`` parameter).
        mesh: the checked mesh (``mesh_check.check_mesh``).
        symmetries: (K, 4, 4) BOP ``symmetries_discrete`` (translation in mm), the
            identity not included; (0, 4, 4) for none.

    """

    name: str
    mesh: CheckedMesh
    symmetries: np.ndarray


def axis_symmetries(mesh: CheckedMesh, axis: str, fold: int) -> np.ndarray:
    """
    (fold - 1, 4, 4) BOP symmetries: turns by 360 / ``fold`` deg about a model axis.

    The axis (``'x'``, ``'y'`` or ``'z'``) runs through the centre of the mesh's box; the
    matrices map model points to model points in millimetres, as BOP writes them.
    """
    if axis not in ('x', 'y', 'z') or fold < 2:
        raise InputError(f'a symmetry is AXIS:FOLD with AXIS x, y or z and FOLD >= 2, got '
                         f'{axis}:{fold}')
    centre = (mesh.vertices.min(axis=0) + mesh.vertices.max(axis=0)) / 2 / MM_TO_M
    k = 'xyz'.index(axis)
    matrices = []
    for turn in range(1, fold):
        angle = 2 * np.pi * turn / fold
        rotation = np.eye(3)
        i, j = [a for a in range(3) if a != k]
        rotation[[i, i, j, j], [i, j, i, j]] = (np.cos(angle), -np.sin(angle), np.sin(angle),
                                                np.cos(angle))
        matrix = np.eye(4)
        matrix[:3, :3], matrix[:3, 3] = rotation, centre - rotation @ centre
        matrices.append(matrix)
    return np.array(matrices)
