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
The map of a static scene: each object's pose in a fixed frame, fused over the views.

Each image comes with the camera's pose in the fixed frame (the robot's TF). Every pose
the pipeline finds in it, with its other refined candidates (``PoseEstimate.alternatives``,
weighed ``ALTERNATIVE_WEIGHT`` times less), becomes a ``ViewedPose`` there
(``views.views_in_world``), and the object's last ``map_window`` views are fused by
consensus (``consensus.fuse_views``): rays from different directions fix the depth one
view cannot see, and the views choose among each other's candidates the rotation they
share. An object is one entry per name (the image's most confident pose of it is taken,
others are left to the per-frame output). An object that was moved shows as views
agreeing with each other but not with the map: when the newest ``map_move_views`` views
are all such, the older ones are dropped and the entry starts afresh from them. An object
out of view or hidden keeps its pose, and its age grows (the stamp it was last seen at).

``poses_in_view`` expresses the map in one image's camera frame: where that image saw the
object and agrees with the map, the two are fused in the camera frame (the view is precise
across its ray and knows nothing of the camera's pose error; the map knows the depth), so
the camera's error does not move the pose across the ray.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.projection import projected_box_uv
from bbpose_ros.core.geometry.rigid import invert_rigid, is_rigid
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.pipeline.poses import Detection, PoseEstimate
from bbpose_ros.core.scene.consensus import agreement, fuse_views, FusedPose
from bbpose_ros.core.scene.views import camera_covariance, ray_covariance, views_in_world
from bbpose_ros.core.scene.views import ViewedPose
from bbpose_ros.core.util.errors import InputError

if TYPE_CHECKING:
    from bbpose_ros.core.data.models import ObjectModel

# Tenths of the diameter: the translation error a map entry's confidence is the chance of
# staying within (the ADD(-S) threshold).
TOLERANCE_DIAMETERS = 0.1
# The stamp step of frames without stamps (a BOP split, offline): a 30 Hz camera's period.
FRAME_PERIOD_NS = 33_333_333
# How much a pipeline's second choices (``PoseEstimate.alternatives``) weigh beside its
# chosen pose: enough to win where other views agree with them, never alone.
ALTERNATIVE_WEIGHT = 0.5


@dataclass(frozen=True)
class MapObject:
    """
    One object of the map, in the fixed frame.

    Attributes:
        object_name: e.g. 'ape'.
        rotation: (3, 3) model-to-world rotation.
        translation: (3,) metres.
        covariance: (3, 3) the translation's covariance, square metres.
        confidence: 0..1 (``consensus.FusedPose.confidence``).
        views: how many views the pose is fused from.
        first_seen_ns: stamp of the oldest view kept (where the entry started afresh).
        last_seen_ns: stamp of the newest view that agrees with the pose.

    """

    object_name: str
    rotation: np.ndarray
    translation: np.ndarray
    covariance: np.ndarray
    confidence: float
    views: int
    first_seen_ns: int
    last_seen_ns: int

    def age_s(self, now_ns: int) -> float:
        """Seconds since the object was last seen to agree with its pose."""
        return (now_ns - self.last_seen_ns) * 1e-9


class _Entry:
    """
    An object's kept views (each a list of candidate ViewedPoses) and their fused pose.

    The candidates are also kept stacked (``consensus``'s layout), with ``agree``, their
    (N, N) ``consensus.agreement``, up to date as views come and go: a new view costs N
    comparisons, not N^2.
    """

    def __init__(self, model: ObjectModel, options: PipelineOptions) -> None:
        self.options = options
        self.symmetries = model.symmetry_transforms
        self.tolerance = TOLERANCE_DIAMETERS * model.diameter
        self.views: list[list[ViewedPose]] = []
        self.stacked = _stack([])
        self.agree = np.zeros((0, 0), dtype=bool)
        self.fused: FusedPose | None = None
        self.seen_ns = 0
        self.pending: list[list[ViewedPose]] = []   # disagreeing views in a row

    @property
    def candidates(self) -> list[ViewedPose]:
        """Every kept candidate, view by view."""
        return [candidate for view in self.views for candidate in view]

    def inlier_candidates(self) -> list[ViewedPose]:
        """Return the candidates the fused pose was made of (one a view at most)."""
        return [c for c, inlier in zip(self.candidates, self.fused.inliers) if inlier]

    def add(self, view: list[ViewedPose]) -> None:
        """
        Take a view (its candidates): added, in place of the newest, or only noted as seen.

        A view from where the newest was taken (rays within ``map_keyframe_deg``) that
        agrees with the fused pose adds nothing but the time it was seen; one that
        disagrees replaces the newest. ``map_move_views`` views in a row, each from a ray
        ``map_keyframe_deg`` or more from the one before (a still camera's frames share
        their errors), whose positions disagree with the fused one and agree with each
        other, mean the object was moved: the entry starts afresh from them.
        """
        new = _stack(view)
        if self._moved(view, new):
            return
        if self.views and _ray_angle_deg(self.views[-1][0], view[0]) < \
                self.options.map_keyframe_deg:
            if self._agreement(_first(new), self._fused_stacked())[0, 0]:
                self.seen_ns = max(self.seen_ns, view[0].stamp_ns)
                return
            self._drop(len(self.views) - 1)
        self._append(view, new)
        self._refit()

    def _fused_stacked(self):
        fused = self.fused
        return fused.rotation[None], fused.translation[None], fused.covariance[None]

    def _moved(self, view, new):
        """Count views in a row placing the object elsewhere; at ``map_move_views``: True."""
        if self.fused is None or self._same_place(_first(new), self._fused_stacked())[0, 0]:
            self.pending = []
            return False
        if self.pending and _ray_angle_deg(self.pending[-1][0], view[0]) < \
                self.options.map_keyframe_deg:
            return False
        if self.pending and not self._same_place(
                _first(new), _stack([v[0] for v in self.pending])).all():
            self.pending = []
        self.pending.append(view)
        if len(self.pending) < self.options.map_move_views:
            return False
        pending, self.pending = self.pending, []
        while self.views:
            self._drop(0)
        self.fused = None
        for kept in pending:
            self._append(kept, _stack(kept))
        self._refit()
        return True

    def _append(self, view, new):
        """Keep a view's candidates: the window's oldest view goes when it is full."""
        if len(self.views) == self.options.map_window:
            self._drop(0)
        old = len(self.agree)
        agree = np.empty((old + len(view), old + len(view)), dtype=bool)
        agree[:old, :old] = self.agree
        agree[old:, :old] = self._agreement(new, self.stacked)
        agree[:old, old:] = agree[old:, :old].T
        agree[old:, old:] = self._agreement(new, new)
        self.agree = agree
        self.stacked = tuple(np.concatenate([old, part]) for old, part in zip(self.stacked, new))
        self.views.append(view)

    def _agreement(self, a, b):
        return agreement(*a[:3], *b[:3], self.symmetries, self.options.map_gate_deg)

    def _same_place(self, a, b):
        """Return (A, B) bool: whether the positions agree, whatever the rotations."""
        return agreement(*a[:3], *b[:3], self.symmetries, 180.0)

    def _refit(self):
        self.fused = fuse_views(*self.stacked, self.agree, self.symmetries,
                                self.options.map_gate_deg, self.tolerance, self.fused)
        self.seen_ns = max([self.seen_ns] + [c.stamp_ns for c in self.inlier_candidates()])

    def _drop(self, index):
        start = sum(len(v) for v in self.views[:index])
        keep = np.ones(len(self.agree), dtype=bool)
        keep[start:start + len(self.views[index])] = False
        self.agree = self.agree[keep][:, keep]
        self.stacked = tuple(part[keep] for part in self.stacked)
        del self.views[index]


def _stack(candidates):
    """(rotations, translations, covariances, weights, view groups) of ViewedPoses."""
    return (np.array([c.rotation for c in candidates], dtype=float).reshape(-1, 3, 3),
            np.array([c.translation for c in candidates], dtype=float).reshape(-1, 3),
            np.array([c.covariance for c in candidates], dtype=float).reshape(-1, 3, 3),
            np.array([max(c.confidence, 1e-3) for c in candidates], dtype=float),
            np.array([c.view for c in candidates], dtype=np.int64))


def _first(stacked):
    """Return the first pose of stacked candidates, stacked."""
    return tuple(part[:1] for part in stacked)


def _ray_angle_deg(a: ViewedPose, b: ViewedPose) -> float:
    """Angle between the rays from two views' cameras to their poses of the object, degrees."""
    ray_a = a.translation - a.camera_position
    ray_b = b.translation - b.camera_position
    cosine = ray_a @ ray_b / (np.linalg.norm(ray_a) * np.linalg.norm(ray_b))
    return float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))


class ObjectMap:
    """
    Each object's pose in the fixed frame, fused over views (see the module docstring).

    ``models``: the objects' models (their symmetries and diameters); ``options``: the
    ``map_*`` settings.
    """

    def __init__(self, models: Mapping[str, ObjectModel], options: PipelineOptions) -> None:
        self.models = models
        self.options = options
        self._entries: dict[str, _Entry] = {}
        self._view_count = 0

    def clear(self) -> None:
        """Forget every object (a new scene)."""
        self._entries.clear()

    def add_view(self, stamp_ns: int, world_from_camera: np.ndarray,
                 camera: CameraIntrinsics, poses: Sequence[PoseEstimate]) -> int:
        """
        Take one image's poses (camera frame), seen from ``world_from_camera`` (4, 4).

        Returns the view's index (for ``poses_in_view``). Raises InputError when the camera
        pose is not a finite rigid transform: nothing is added then.
        """
        world_from_camera = _checked(world_from_camera)
        focal = 0.5 * (camera.fx + camera.fy)
        view = self._view_count
        self._view_count += 1
        for pose in _most_confident(poses, self.models):
            name = pose.object_name
            entry = self._entries.get(name) or _Entry(self.models[name], self.options)
            entry.add(views_in_world(name, view, stamp_ns, world_from_camera,
                                     _candidates(pose), focal, self.options))
            self._entries[name] = entry         # kept once it holds a fused pose
        return view

    def objects(self) -> list[MapObject]:
        """Return the map's objects, by name."""
        found = []
        for name in sorted(self._entries):
            entry = self._entries[name]
            fused = entry.fused
            found.append(MapObject(name, fused.rotation, fused.translation, fused.covariance,
                                   fused.confidence, int(fused.inliers.sum()),
                                   entry.views[0][0].stamp_ns, entry.seen_ns))
        return found

    def poses_in_view(self, world_from_camera: np.ndarray, camera: CameraIntrinsics,
                      poses: Sequence[PoseEstimate] = (),
                      view: int | None = None) -> list[PoseEstimate]:
        """
        Return the map's objects in one image's camera frame, those in front and in the image.

        ``poses``: that image's own poses (camera frame) and ``view`` its index from
        ``add_view``: where the map still holds that view as agreeing with it, the image's
        pose is fused with the map's (see the module docstring) and its detection kept.
        Each pose's source is 'map' and its confidence the map's.
        """
        camera_from_world = invert_rigid(_checked(world_from_camera))
        own = {p.object_name: p for p in _most_confident(poses, self.models)}
        found = []
        for item in self.objects():
            rotation = camera_from_world[:3, :3] @ item.rotation
            translation = camera_from_world[:3, :3] @ item.translation + camera_from_world[:3, 3]
            box = _box_in_image(self.models[item.object_name], camera, rotation, translation)
            if box is None:
                continue
            anchor = None if view is None else self._inlier_of(item.object_name, view)
            detection = Detection(item.object_name, item.confidence, box)
            if anchor is not None:
                translation = self._anchored(camera_from_world, item, translation, anchor,
                                             camera)
                if item.object_name in own:
                    detection = own[item.object_name].detection
            found.append(PoseEstimate(detection, rotation, translation, item.confidence, 'map'))
        return found

    def _inlier_of(self, name, view):
        """Return the object's candidate of view ``view`` the fused pose holds, or None."""
        return next((c for c in self._entries[name].inlier_candidates() if c.view == view),
                    None)

    def _anchored(self, camera_from_world, item, translation, anchor, camera):
        """Fuse the map's translation (camera frame) with the view's own, by covariance."""
        rotation_cw = camera_from_world[:3, :3]
        distance = float(np.linalg.norm(translation))
        prior = rotation_cw @ item.covariance @ rotation_cw.T + \
            camera_covariance(distance, self.options) * np.eye(3)
        measured = ray_covariance(anchor.translation_camera, 0.5 * (camera.fx + camera.fy),
                                  self.options)
        prior_info, measured_info = np.linalg.inv(prior), np.linalg.inv(measured)
        return np.linalg.solve(prior_info + measured_info, prior_info @ translation
                               + measured_info @ anchor.translation_camera)


def _checked(world_from_camera):
    matrix = np.asarray(world_from_camera, dtype=float)
    if not is_rigid(matrix, tolerance=1e-4):
        raise InputError('camera pose: not a finite rigid transform (4 x 4, orthonormal '
                         'rotation, last row 0 0 0 1)')
    return matrix


def _candidates(pose):
    """(rotation, translation, weight) of a pose and its alternatives (camera frame)."""
    return [(pose.rotation, pose.translation, pose.confidence)] + [
        (rotation, translation, ALTERNATIVE_WEIGHT * score)
        for rotation, translation, score in pose.alternatives
        if _finite(rotation, translation, score)]


def _most_confident(poses, models):
    """Return the most confident pose of each object the map has a model of."""
    best = {}
    for pose in poses:
        name = pose.object_name
        if name in models and _finite(pose.rotation, pose.translation, pose.confidence) and (
                name not in best or pose.confidence > best[name].confidence):
            best[name] = pose
    return list(best.values())


def _finite(rotation, translation, confidence):
    """Tell whether a pose and its confidence are all finite numbers."""
    return bool(np.all(np.isfinite(rotation)) and np.all(np.isfinite(translation))
                and np.isfinite(confidence))


def _box_in_image(model, camera, rotation, translation):
    """Return the projected box where the model is in front and overlaps the image, or None."""
    try:
        box = projected_box_uv(camera, model.hull_points, rotation, translation)
    except InputError:
        return None
    inside = box[0] < camera.width and box[1] < camera.height and box[2] > 0 and box[3] > 0
    return box if inside else None
