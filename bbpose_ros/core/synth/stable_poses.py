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
Poses in which a rigid mesh rests on a horizontal plane, cached per mesh.

The stable poses are those of ``trimesh.poses.compute_stable_poses``: the faces of the convex
hull a body can lie on, with the probability that a body dropped in a random orientation
comes to rest on each (the share of directions from the centre of mass that end on it).
Rotations map the model frame to a world frame whose z axis points up from the plane;
any turn about z keeps a pose stable. Computing them takes seconds per LM-O mesh, so they
are cached in a folder, in files named after a digest of the mesh.
"""

from dataclasses import dataclass
import os
from pathlib import Path

import numpy as np
import numpy.typing as npt
import trimesh

from bbpose_ros.core.data.fingerprints import sha256_of_arrays
from bbpose_ros.core.util.files import atomic_output

# Stable poses less likely than this are left out (slivers of the hull).
MIN_PROBABILITY = 0.01


@dataclass(frozen=True)
class StablePoses:
    """
    The resting orientations of one mesh.

    Attributes:
        rotations: (P, 3, 3) model-to-world rotations; the world z axis is the plane normal.
        probabilities: (P,) chance of each when dropped at random, summing to 1.

    """

    rotations: np.ndarray
    probabilities: np.ndarray

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        """(3, 3) one of the rotations, by probability, turned by a random angle about z."""
        rotation = self.rotations[rng.choice(len(self.probabilities), p=self.probabilities)]
        return yaw_rotation(rng.uniform(0.0, 2.0 * np.pi)) @ rotation


def yaw_rotation(angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` radians about the world z axis."""
    cos, sin = np.cos(angle), np.sin(angle)
    return np.array([[cos, -sin, 0.0], [sin, cos, 0.0], [0.0, 0.0, 1.0]])


def resting_height(rotation: npt.ArrayLike, hull_points: npt.ArrayLike) -> float:
    """Height (metres) that lifts (N, 3) model points at ``rotation`` onto the plane z = 0."""
    return float(-(np.asarray(hull_points, dtype=float) @ np.asarray(rotation)[2]).min())


def default_cache_dir() -> Path:
    """$BBPOSE_STABLE_POSE_CACHE, else ~/.cache/bbpose/stable_poses."""
    return Path(os.environ.get('BBPOSE_STABLE_POSE_CACHE',
                               Path.home() / '.cache' / 'bbpose' / 'stable_poses'))


def compute_stable_poses(vertices: npt.ArrayLike, faces: npt.ArrayLike) -> StablePoses:
    """
    Compute the stable poses of a mesh, (V, 3) vertices in metres and (F, 3) faces.

    The centre of mass is the mesh's own when it is watertight, else its convex hull's.
    Poses under MIN_PROBABILITY are left out, unless none is more likely.
    """
    mesh = trimesh.Trimesh(np.asarray(vertices, dtype=float), np.asarray(faces), process=False)
    hull = mesh.convex_hull
    center = mesh.center_mass if mesh.is_watertight else hull.center_mass
    transforms, probabilities = trimesh.poses.compute_stable_poses(hull, center_mass=center)
    probabilities = np.asarray(probabilities, dtype=float)
    if len(probabilities) == 0:     # a degenerate hull: rest it as it is
        return StablePoses(np.eye(3)[None], np.ones(1))
    keep = probabilities >= min(MIN_PROBABILITY, probabilities.max())
    rotations = np.asarray(transforms)[keep, :3, :3]
    probabilities = probabilities[keep]
    return StablePoses(rotations, probabilities / probabilities.sum())


def load_stable_poses(name: str, vertices: npt.ArrayLike, faces: npt.ArrayLike,
                      cache_dir: Path | str | None = None) -> StablePoses:
    """
    Load the stable poses of mesh ``name`` from the cache, or compute and cache them.

    An unwritable cache folder only costs the computation next time.
    """
    vertices = np.ascontiguousarray(vertices, dtype=np.float64)
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    digest = sha256_of_arrays(vertices, faces)[:16]
    path = Path(cache_dir if cache_dir is not None else default_cache_dir()) / \
        f'{name}-{digest}.npz'
    if path.is_file():
        with np.load(path) as stored:
            return StablePoses(stored['rotations'], stored['probabilities'])
    poses = compute_stable_poses(vertices, faces)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_output(path) as tmp, open(tmp, 'wb') as stream:
            np.savez(stream, rotations=poses.rotations, probabilities=poses.probabilities)
    except OSError:
        pass
    return poses
