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
Where a table scene's meshes rest and where its camera stands (``table_scenes``' layout).

World frame: the table is z = 0, z up, the cluster centred on the origin. Each mesh rests
on the table (its lowest hull point at z = 0) in a stable or upright pose, and the meshes'
footprints (their hulls projected on the table) do not overlap, so no two meshes
intersect (``place_meshes``); a camera looks down at the cluster (``draw_camera_pose``,
``look_at``). Everything is drawn from the sample's random stream, in the order
``TableScenes`` draws it.
"""

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from bbpose_ros.core.render.gl_renderer import Draw
from bbpose_ros.core.synth.stable_poses import resting_height, StablePoses, yaw_rotation
from bbpose_ros.core.synth.table_config import TableConfig

# Attempts at a free spot on the table per mesh before it is left out.
_SPOT_ATTEMPTS = 40
# Smallest gap between two footprints on the table (metres).
_FOOTPRINT_GAP = 0.002


@dataclass(frozen=True)
class PlacedMesh:
    """
    A mesh resting on the table.

    Attributes:
        key: its renderer key ('target/ape', 'distractor/can', 'shape/3').
        rotation: (3, 3) model-to-world rotation.
        translation: (3,) model origin in the world frame, metres (z lifts it onto the table).

    """

    key: str
    rotation: np.ndarray
    translation: np.ndarray


@dataclass(frozen=True)
class TableLayout:
    """
    The world of one table scene (world frame: table z = 0, z up).

    Attributes:
        meshes: tuple of ``PlacedMesh``, the targets first.
        world_to_camera: (4, 4) rigid map of world points to the camera frame (metres).
        draws: tuple of the ``Draw`` (camera frame) the image was rendered with, one per
            mesh, in the same order.

    """

    meshes: tuple[PlacedMesh, ...]
    world_to_camera: np.ndarray
    draws: tuple[Draw, ...]


def look_at(position: np.ndarray, target: np.ndarray, roll: float) -> np.ndarray:
    """
    (4, 4) world-to-camera map of an OpenCV camera at ``position`` looking at ``target``.

    Unrolled, the camera's x axis is horizontal (the world z axis points up in the image);
    then it turns by ``roll`` radians about its optical axis. The camera must not look
    straight down or up.
    """
    forward = target - position
    forward = forward / np.linalg.norm(forward)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    axes = np.stack([right, np.cross(forward, right), forward])
    cos, sin = np.cos(roll), np.sin(roll)
    axes = np.array([[cos, -sin, 0.0], [sin, cos, 0.0], [0.0, 0.0, 1.0]]) @ axes
    transform = np.eye(4)
    transform[:3, :3] = axes
    transform[:3, 3] = -axes @ position
    return transform


def footprint(points_xy: np.ndarray) -> np.ndarray:
    """(K, 2) convex polygon (counter-clockwise) of (N, 2) points on the table, metres."""
    hull = cv2.convexHull(points_xy.astype(np.float32), clockwise=False)
    return hull.reshape(-1, 2).astype(float)


def polygons_overlap(first: np.ndarray, second: np.ndarray, gap: float = 0.0) -> bool:
    """
    Tell whether two convex polygons (K, 2) come closer than ``gap`` along every axis.

    The separating-axis test over both polygons' edge normals: convex polygons that are
    ``gap`` apart along some edge normal are disjoint.
    """
    for polygon in (first, second):
        edges = np.roll(polygon, -1, axis=0) - polygon
        normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1)
        length = np.linalg.norm(normals, axis=1)
        normals = normals[length > 1e-12] / length[length > 1e-12, None]
        a, b = first @ normals.T, second @ normals.T
        if np.any((a.min(axis=0) > b.max(axis=0) + gap) |
                  (b.min(axis=0) > a.max(axis=0) + gap)):
            return False
    return True


def place_meshes(rng: np.random.Generator, radius: float, config: TableConfig,
                 target_names: Sequence[str], clutter_keys: Sequence[str],
                 hulls: Mapping[str, np.ndarray], stable: Mapping[str, StablePoses]
                 ) -> list[PlacedMesh]:
    """
    Targets and clutter resting on the table, footprints apart (targets listed first).

    A mesh that finds no free spot in ``_SPOT_ATTEMPTS`` tries, in a disc growing to
    twice ``radius``, is left out.

    Args:
        rng: the sample's random stream (drawn from).
        radius: radius of the cluster, metres.
        config: TableConfig (targets and clutter per image, upright probability).
        target_names: the targets' names ('target/<name>' renderer keys).
        clutter_keys: renderer keys of the clutter ('distractor/...', 'shape/...').
        hulls: {renderer key: (K, 3) hull points, model frame, metres}.
        stable: {renderer key: StablePoses}.

    """
    count = min(int(rng.integers(config.targets_per_image[0],
                                 config.targets_per_image[1] + 1)), len(target_names))
    keys = [f'target/{target_names[i]}'
            for i in rng.choice(len(target_names), count, replace=False)]
    clutter = int(rng.integers(config.clutter_per_image[0], config.clutter_per_image[1] + 1))
    keys += [clutter_keys[i] for i in rng.integers(len(clutter_keys), size=clutter)]
    # Targets and clutter mixed: clutter stands between the targets too.
    order = rng.permutation(count + clutter)
    placed, polygons = {}, []
    for k in order:
        key = keys[k]
        if not key.startswith('shape/') and rng.random() < config.upright_probability:
            rotation = yaw_rotation(rng.uniform(0.0, 2.0 * np.pi))
        else:
            rotation = stable[key].sample(rng)
        points = hulls[key] @ rotation.T
        shape = footprint(points[:, :2])
        for attempt in range(_SPOT_ATTEMPTS):
            # The disc grows while the spots tried are taken.
            spot = in_disc(rng, radius * (1.0 + attempt / _SPOT_ATTEMPTS))
            polygon = shape + spot
            if not any(polygons_overlap(polygon, other, _FOOTPRINT_GAP)
                       for other in polygons):
                polygons.append(polygon)
                placed[k] = PlacedMesh(key, rotation, np.array(
                    [spot[0], spot[1], resting_height(rotation, hulls[key])]))
                break
    return [placed[k] for k in sorted(placed)]


def draw_camera_pose(rng: np.random.Generator, radius: float, config: TableConfig
                     ) -> np.ndarray:
    """Draw the world-to-camera (4, 4) of a camera looking down at the cluster (metres)."""
    target = np.append(in_disc(rng, config.look_offset * radius), 0.0)
    low, high = np.sin(np.radians(config.camera_elevation_range_deg))
    elevation = np.arcsin(rng.uniform(low, high))
    azimuth = rng.uniform(0.0, 2.0 * np.pi)
    direction = np.array([np.cos(elevation) * np.cos(azimuth),
                          np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])
    position = target + rng.uniform(*config.camera_distance_range) * direction
    return look_at(position, target,
                   np.radians(rng.uniform(*config.inplane_range_deg)))


def in_disc(rng: np.random.Generator, radius: float) -> np.ndarray:
    """(2,) a point uniform in the disc of ``radius`` about the origin."""
    angle = rng.uniform(0.0, 2.0 * np.pi)
    return radius * np.sqrt(rng.random()) * np.array([np.cos(angle), np.sin(angle)])
