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
Scoring the map: each frame's poses replaced by the scene's map, seen from that frame.

``bbpose eval --fuse``: the frames of one BOP scene are one static scene (a map is started
afresh for each), in image id order, each with its camera pose. ``causal`` gives each frame
the map built from the frames up to it (what a robot has when the image arrives);
``final`` gives every frame the map after the whole scene (what it has after looking).
Only images, camera poses and the pipeline's poses feed the map, never the ground truth.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from itertools import groupby
import time
from typing import Any, TYPE_CHECKING

import numpy as np

from bbpose_ros.core.geometry.rotations import log_so3, nearest_rotation
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.pipeline.poses import PoseEstimate
from bbpose_ros.core.scene.object_map import FRAME_PERIOD_NS, MapObject, ObjectMap
from bbpose_ros.core.util.errors import InputError

if TYPE_CHECKING:
    from bbpose_ros.core.data.bop import BopFrame
    from bbpose_ros.core.data.models import ObjectModel

FUSE_MODES = ('none', 'causal', 'final')
# The map's stability is its spread over an object's last this many frames.
STABILITY_FRAMES = 100
# A true position that jumps more than this between two frames: the object was moved.
MOVE_M = 0.01


def frame_camera_poses(frames: Sequence[BopFrame], noise: tuple[float, float] | None = None,
                       seed: int = 0) -> list[np.ndarray]:
    """
    (4, 4) world_from_camera of each frame, with ``noise`` (mm, deg) added if given.

    Raises InputError naming the first frame whose scene_camera.json has no camera pose.
    """
    from bbpose_ros.core.eval.static_stretches import noisy_pose
    rng = np.random.default_rng(seed)
    poses = []
    for frame in frames:
        if frame.world_from_camera is None:
            raise InputError(
                f'scene {frame.scene_id} image {frame.image_id} has no camera pose '
                '(cam_R_w2c / cam_t_w2c in its scene_camera.json); bbpose static-scenes '
                'writes a labelled split as static scenes with camera poses')
        pose = frame.world_from_camera
        poses.append(pose if noise is None else noisy_pose(pose, *noise, rng))
    return poses


@dataclass(frozen=True)
class MapRun:
    """
    What the map gave over a run of frames (``fused_poses``).

    Attributes:
        poses: per frame, its poses as the map gives them (camera frame).
        objects: per frame, the map's objects after it ({name: MapObject}, fixed frame):
            after the frame itself (causal) or after its whole scene (final).
        map_ms: per frame, how long taking its poses into the map took, milliseconds.

    """

    poses: list[list[PoseEstimate]]
    objects: list[dict[str, MapObject]]
    map_ms: list[float]


def fused_poses(frames: Sequence[BopFrame], poses: Sequence[Sequence[PoseEstimate]],
                camera_poses: Sequence[np.ndarray], models: Mapping[str, ObjectModel],
                options: PipelineOptions, mode: str) -> MapRun:
    """
    Each frame's poses as the map gives them (module docstring), frames in scene order.

    ``poses``: the pipeline's poses of each frame (camera frame); ``camera_poses``: each
    frame's (4, 4) world_from_camera.
    """
    if mode not in FUSE_MODES[1:]:
        raise InputError(f'fuse: {mode!r} is not one of {", ".join(FUSE_MODES[1:])}')
    fused, objects, map_ms = [], [], []
    for _, scene in groupby(range(len(frames)), key=lambda k: frames[k].scene_id):
        scene = list(scene)
        scene_map = ObjectMap(models, options)
        views = {}
        for k in scene:
            start = time.perf_counter()
            views[k] = scene_map.add_view(frames[k].image_id * FRAME_PERIOD_NS, camera_poses[k],
                                          frames[k].camera, poses[k])
            map_ms.append((time.perf_counter() - start) * 1e3)
            if mode == 'causal':
                fused.append(scene_map.poses_in_view(camera_poses[k], frames[k].camera,
                                                     poses[k], views[k]))
                objects.append({o.object_name: o for o in scene_map.objects()})
        if mode == 'final':
            fused.extend(scene_map.poses_in_view(camera_poses[k], frames[k].camera, poses[k],
                                                 views[k]) for k in scene)
            objects.extend([{o.object_name: o for o in scene_map.objects()}] * len(scene))
    return MapRun(fused, objects, map_ms)


def map_track_report(frames: Sequence[BopFrame], camera_poses: Sequence[np.ndarray],
                     run: MapRun, window: int = STABILITY_FRAMES) -> dict[str, Any]:
    """
    How still the map holds each object, and how soon it follows one that was moved.

    Per scene and object (world frame, the ground truth carried there by each frame's
    camera pose): ``stability``: the spread of the map's pose over the object's last
    ``window`` frames in the map (since its last move), as the root-mean-square distance
    from their mean (mm) and angle from their mean rotation (deg), the worst scene per
    object, a list of {'object', 'frames', 'translation_mm', 'rotation_deg'}; ``moves``:
    where the truth jumps by more than ``MOVE_M`` between two frames, in how many frames
    the map's pose comes nearer the new place than the old one and stays so (None: never).
    """
    stability, moves = {}, []     # stability: {object: its worst scene's spread}
    for _, scene in groupby(range(len(frames)), key=lambda k: frames[k].scene_id):
        scene = list(scene)
        truth = _truth_in_world(frames, camera_poses, scene)
        names = sorted({name for k in scene for name in run.objects[k]})
        for name in names:
            jumps = _jumps(truth.get(name, {}))
            since = jumps[-1][0] if jumps else scene[0]
            track = [run.objects[k][name] for k in scene if k >= since and name in
                     run.objects[k]][-window:]
            if len(track) >= 2:
                spread = _spread(track)
                worst = stability.get(name)
                if worst is None or spread['translation_mm'] > worst['translation_mm']:
                    stability[name] = spread
            for k, (old, new) in jumps:
                moves.append({'object': name, 'scene': frames[k].scene_id,
                              'image_id': frames[k].image_id,
                              'frames_to_follow': _frames_to_follow(run, scene, k, name, old,
                                                                    new)})
    return {'window_frames': window,
            'stability': [dict(object=name, **row) for name, row in sorted(stability.items())],
            'moves': moves}


def _truth_in_world(frames, camera_poses, scene):
    """{object: {frame index: (3,) true position in the world frame}} of a scene."""
    truth = {}
    for k in scene:
        pose = camera_poses[k]
        for instance in frames[k].instances:
            truth.setdefault(instance.object_name, {})[k] = \
                pose[:3, :3] @ instance.translation + pose[:3, 3]
    return truth


def _jumps(positions):
    """[(frame index, (old, new) position)] where an object's truth jumps by > MOVE_M."""
    ordered = sorted(positions.items())
    return [(k, (before, after)) for (_, before), (k, after) in zip(ordered, ordered[1:])
            if np.linalg.norm(after - before) > MOVE_M]


def _spread(track):
    """RMS distance (mm) and angle (deg) of map poses from their mean."""
    translations = np.array([o.translation for o in track])
    rotations = np.array([o.rotation for o in track])
    mean_rotation = nearest_rotation(rotations.mean(axis=0))
    angles = np.degrees(np.linalg.norm(log_so3(np.swapaxes(rotations, 1, 2) @ mean_rotation),
                                       axis=1))
    distances = np.linalg.norm(translations - translations.mean(axis=0), axis=1)
    return {'frames': len(track), 'translation_mm': float(np.sqrt(np.mean(distances ** 2)) * 1e3),
            'rotation_deg': float(np.sqrt(np.mean(angles ** 2)))}


def _frames_to_follow(run, scene, start, name, old, new):
    """Frames from ``start`` until the map's pose stays nearer ``new`` than ``old``."""
    after = [k for k in scene if k >= start]
    nearer = [name in run.objects[k] and np.linalg.norm(run.objects[k][name].translation - new)
              < np.linalg.norm(run.objects[k][name].translation - old) for k in after]
    for count in range(len(after)):
        if all(nearer[count:]):
            return count
    return None


def format_map_tracks(tracks: Mapping[str, Any]) -> str:
    """Say a ``map_track_report`` in lines: each object's spread, each move followed."""
    lines = [f'map stability (spread over an object\'s last {tracks["window_frames"]} frames '
             'in the map, worst scene):']
    lines += [f'  {row["object"]}: {row["translation_mm"]:.2f} mm, {row["rotation_deg"]:.3f} '
              f'deg over {row["frames"]} frames' for row in tracks['stability']]
    lines += [f'  {move["object"]} moved at scene {move["scene"]} image {move["image_id"]}: '
              + ('never followed' if move['frames_to_follow'] is None else
                 f'followed in {move["frames_to_follow"]} frames') for move in tracks['moves']]
    return '\n'.join(lines)
