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
One view of an object as the map takes it: its pose in the fixed frame and how sure it is.

A single RGB view places an object well across its viewing ray (the silhouette fits to a
pixel or two) and poorly along it (a box a few per cent too large or small moves the depth
as much). A view's translation covariance is therefore long along the ray and short across
it, and the camera's own pose error (the robot's TF) adds to it in every direction: a
camera rotation error moves the object by the angle times its distance. Views from
different directions intersect their rays; ``consensus`` fuses them by these covariances.

Frames: ``world`` is the map's fixed frame, ``camera`` the optical frame of the image
(z forward). Units: metres, radians inside, millimetres and degrees where a setting's name
says so.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math

import numba
import numpy as np

from bbpose_ros.core.inference.options import PipelineOptions

MM = 1e-3


@dataclass(frozen=True)
class ViewedPose:
    """
    An object's pose seen in one view, in the fixed frame.

    Attributes:
        object_name: e.g. 'ape'.
        view: index of the view in the map's sequence (0, 1, ...).
        stamp_ns: the image's stamp, nanoseconds.
        rotation: (3, 3) model-to-world rotation.
        translation: (3,) the model origin in the world frame, metres.
        covariance: (3, 3) translation covariance in the world frame, square metres (the
            view's ray model plus the camera's pose error).
        camera_position: (3,) the camera's optical centre in the world frame, metres.
        confidence: the weight of the pose in the map (0..1: its confidence,
            ``PoseEstimate.confidence``, lowered for a pipeline's second choice).
        translation_camera: (3,) the model origin in the view's camera frame, metres.

    """

    object_name: str
    view: int
    stamp_ns: int
    rotation: np.ndarray
    translation: np.ndarray
    covariance: np.ndarray
    camera_position: np.ndarray
    confidence: float
    translation_camera: np.ndarray


@numba.njit(cache=True, nogil=True)
def _ray_covariance(translation_camera, focal_px, depth_sigma, across_sigma_px):
    distance = math.sqrt(translation_camera @ translation_camera)
    ray = translation_camera / max(distance, 1e-9)
    along = (depth_sigma * distance) ** 2
    across = (across_sigma_px * distance / focal_px) ** 2
    return across * np.eye(3) + (along - across) * np.outer(ray, ray)


def ray_covariance(translation_camera: np.ndarray, focal_px: float,
                   options: PipelineOptions) -> np.ndarray:
    """
    Covariance (3, 3) of one view's translation in the camera frame, square metres.

    Along the ray through the model origin the standard deviation is ``map_depth_sigma``
    times the distance; across it ``map_across_sigma_px`` pixels at that distance
    (``focal_px``: the camera's mean focal length in pixels).
    """
    return _ray_covariance(np.asarray(translation_camera, dtype=float), float(focal_px),
                           options.map_depth_sigma, options.map_across_sigma_px)


def camera_covariance(distance_m: float, options: PipelineOptions) -> float:
    """
    Variance (square metres, each axis) the camera's pose error adds to a point.

    The error of the camera's position (``map_camera_sigma_mm``) and of its rotation
    (``map_camera_sigma_deg``, times the point's distance from the camera).
    """
    return (options.map_camera_sigma_mm * MM) ** 2 + \
        (math.radians(options.map_camera_sigma_deg) * distance_m) ** 2


@numba.njit(cache=True, nogil=True)
def _world_covariances(rotation_wc, translations_camera, focal_px, depth_sigma,
                       across_sigma_px, camera_m, camera_rad):
    covariances = np.empty((translations_camera.shape[0], 3, 3))
    for k in range(translations_camera.shape[0]):
        t = translations_camera[k]
        covariance = rotation_wc @ _ray_covariance(t, focal_px, depth_sigma, across_sigma_px) \
            @ rotation_wc.T
        variance = camera_m ** 2 + (camera_rad * math.sqrt(t @ t)) ** 2
        for axis in range(3):
            covariance[axis, axis] += variance
        covariances[k] = covariance
    return covariances


def views_in_world(object_name: str, view: int, stamp_ns: int, world_from_camera: np.ndarray,
                   poses: Sequence[tuple[np.ndarray, np.ndarray, float]], focal_px: float,
                   options: PipelineOptions) -> list[ViewedPose]:
    """
    Carry one view's candidate poses from the camera frame into the fixed frame.

    ``world_from_camera``: (4, 4) the camera's pose in the fixed frame at the image's stamp;
    ``poses``: (rotation (3, 3), translation (3,) metres, confidence) model-to-camera. Each
    covariance is the view's ray model (``ray_covariance``) turned into the fixed frame,
    plus the camera's error (``camera_covariance``).
    """
    rotation_wc, position = world_from_camera[:3, :3], world_from_camera[:3, 3].copy()
    translations = np.array([t for _, t, _ in poses], dtype=float).reshape(-1, 3)
    covariances = _world_covariances(
        np.ascontiguousarray(rotation_wc), translations, float(focal_px),
        options.map_depth_sigma, options.map_across_sigma_px, options.map_camera_sigma_mm * MM,
        math.radians(options.map_camera_sigma_deg))
    return [ViewedPose(object_name, view, stamp_ns, rotation_wc @ rotation,
                       rotation_wc @ translation + position, covariance, position,
                       float(confidence), translation)
            for (rotation, _, confidence), translation, covariance
            in zip(poses, translations, covariances)]
