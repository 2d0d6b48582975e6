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
A labelled BOP split as static scenes with camera poses: an evaluation tool for the map.

LM-O-like recordings move their objects every few frames while the camera moves, and BOP
gives them no camera poses. Consecutive frames (image id order) whose annotated objects
keep every pairwise distance within ``tolerance_m`` of every earlier frame of the stretch
form one static scene. Its world frame is its first frame's camera frame, and each frame's
camera pose follows from its annotated objects: the rigid transform that best carries the
objects' 3D box corners from the first frame to this one (least squares, Kabsch).
Optional noise stands in for a robot's TF error.

This reads the ground truth (``scene_gt``): it makes evaluation data, never training data,
and the map it feeds reads only the camera poses and the images.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

from bbpose_ros.core.geometry.rigid import rigid_matrix
from bbpose_ros.core.geometry.rotations import exp_so3
from bbpose_ros.core.util.errors import InputError

if TYPE_CHECKING:
    from bbpose_ros.core.data.bop import BopFrame
    from bbpose_ros.core.data.models import ObjectModel


def _centres(frame):
    """{obj_id: (3,) translation} of the frame's annotated objects, one instance each."""
    ids = [i.obj_id for i in frame.instances]
    return {i.obj_id: i.translation for i in frame.instances if ids.count(i.obj_id) == 1}


def _same_layout(a, b, tolerance_m):
    """Tell whether two frames share two or more objects, all at the same distances."""
    common = sorted(set(a) & set(b))
    if len(common) < 2:
        return False
    return all(abs(np.linalg.norm(a[i] - a[j]) - np.linalg.norm(b[i] - b[j])) <= tolerance_m
               for k, i in enumerate(common) for j in common[k + 1:])


def static_stretches(frames: Sequence[BopFrame],
                     tolerance_m: float = 0.005) -> list[list[BopFrame]]:
    """
    Split frames (sorted by scene and image id) into static scenes (module docstring).

    A frame that agrees with no stretch starts one; a stretch may hold a single frame.
    """
    stretches = []
    for frame in frames:
        centres = _centres(frame)
        current = stretches[-1] if stretches else None
        if current is not None and current[0].scene_id == frame.scene_id and all(
                _same_layout(_centres(f), centres, tolerance_m) for f in current):
            current.append(frame)
        else:
            stretches.append([frame])
    return stretches


def _kabsch(source, target):
    """(4, 4) rigid transform minimising |target - (R source + t)|^2 over (N, 3) points."""
    source_mean, target_mean = source.mean(0), target.mean(0)
    u, _, vt = np.linalg.svd((target - target_mean).T @ (source - source_mean))
    flip = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    rotation = u @ flip @ vt
    return rigid_matrix(rotation, target_mean - rotation @ source_mean)


def camera_poses(stretch: Sequence[BopFrame],
                 models: Mapping[str, ObjectModel]) -> list[np.ndarray]:
    """
    (4, 4) world_from_camera of each frame of a static scene (world: the first camera).

    Fitted on the 3D box corners of the objects each frame shares with the first (only
    objects with a model count).
    """
    def corners(frame):
        once = _centres(frame)          # objects with one instance: no pairing to guess
        return {i.obj_id: i.rotation @ models[i.object_name].box_corners.T
                + i.translation[:, None] for i in frame.instances
                if i.object_name in models and i.obj_id in once}

    world = corners(stretch[0])
    poses = []
    for frame in stretch:
        seen = corners(frame)
        common = sorted(set(world) & set(seen))
        if not common:
            raise InputError(f'scene {frame.scene_id} image {frame.image_id} shares no '
                             "modelled object with its scene's first frame: no camera pose")
        poses.append(_kabsch(np.hstack([seen[k] for k in common]).T,
                             np.hstack([world[k] for k in common]).T))
    return poses


def noisy_pose(world_from_camera: np.ndarray, sigma_mm: float, sigma_deg: float,
               rng: np.random.Generator) -> np.ndarray:
    """
    Give a camera pose a TF-like error: isotropic Gaussian offsets of the given RMS size.

    The position moves by a vector whose root-mean-square length is ``sigma_mm``; the
    camera turns about a random axis by a rotation vector whose RMS angle is ``sigma_deg``.
    """
    offset = rng.normal(scale=sigma_mm * 1e-3 / np.sqrt(3.0), size=3)
    turn = exp_so3(rng.normal(scale=np.deg2rad(sigma_deg) / np.sqrt(3.0), size=3))
    return rigid_matrix(world_from_camera[:3, :3] @ turn, world_from_camera[:3, 3] + offset)
