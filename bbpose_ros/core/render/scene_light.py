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
Scene light of ``MeshRenderer.render_lit``: point lights with shadow maps, materials, planes.

Ambient light plus up to ``MAX_LIGHTS`` point lights, each with Blinn-Phong specular
highlights and a shadow map: a depth image of the meshes seen from the light, aimed at a
sphere that holds them. Only meshes cast shadows; planes (a table, walls) receive them.
Everything is in the OpenCV camera frame of the image (x right, y down, z forward), metres.
"""

from collections.abc import Sequence
from dataclasses import dataclass, field
import math

import numpy as np

from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.render.clip_space import opengl_projection
from bbpose_ros.core.render.lit_shaders import MAX_LIGHTS
from bbpose_ros.core.util.errors import InputError

__all__ = ['MAX_LIGHTS', 'Material', 'PointLight', 'SceneLights', 'SHADOW_MAP_SIZE',
           'TexturedPlane', 'light_matrix']

# Side of each light's shadow map, pixels.
SHADOW_MAP_SIZE = 1024


@dataclass(frozen=True)
class PointLight:
    """
    A point light that casts shadows.

    Attributes:
        position: (3,) light position, camera frame, metres.
        color: (3,) RGB intensity (colour factor of diffuse and specular light).

    """

    position: tuple[float, float, float]
    color: tuple[float, float, float] = (0.6, 0.6, 0.6)


@dataclass(frozen=True)
class SceneLights:
    """
    The light of one lit image.

    Attributes:
        lights: up to MAX_LIGHTS ``PointLight``.
        ambient: (3,) RGB ambient intensity.
        shadow_center: (3,) centre of the sphere the shadow maps cover, camera frame, metres.
        shadow_radius: radius of that sphere, metres; shadows fall only inside it.
        cast_shadows: whether meshes cast shadows (False: the same diffuse light and
            highlights, nothing in shadow; for measuring what shadows are worth).

    """

    lights: tuple[PointLight, ...]
    ambient: tuple[float, float, float] = (0.5, 0.5, 0.5)
    shadow_center: tuple[float, float, float] = (0.0, 0.0, 1.0)
    shadow_radius: float = 0.5
    cast_shadows: bool = True


@dataclass(frozen=True)
class Material:
    """
    Specular material of one draw: highlight = specular x max(n . h, 0) ^ shininess.

    Attributes:
        specular: strength of the highlight (0: matte).
        shininess: Blinn-Phong exponent (low: rough and broad, high: smooth and sharp).

    """

    specular: float = 0.0
    shininess: float = 16.0


@dataclass(frozen=True)
class TexturedPlane:
    """
    A textured rectangle (table top, wall) drawn behind or under the meshes, id 0.

    Attributes:
        rotation: (3, 3) plane-to-camera rotation; the plane is its frame's z = 0, its
            normal +z.
        translation: (3,) plane centre in the camera frame, metres.
        half_size: (2,) half its extent along its x and y axes, metres.
        texture: (T, T2, 3) uint8 RGB image, repeated over the plane.
        tile: metres of plane one repetition of the texture covers.
        material: its specular ``Material``.

    """

    rotation: np.ndarray
    translation: np.ndarray
    half_size: tuple[float, float]
    texture: np.ndarray
    tile: float = 1.0
    material: Material = field(default_factory=Material)


def light_matrix(light: PointLight, center: Sequence[float], radius: float) -> np.ndarray:
    """
    (4, 4) map of camera-frame points to the clip space of ``light``'s shadow map.

    The map looks from the light at ``center`` and just holds the sphere of ``radius``.
    """
    position = np.asarray(light.position, dtype=float)
    forward = np.asarray(center, dtype=float) - position
    distance = float(np.linalg.norm(forward))
    if distance <= radius:
        raise InputError(f'a light at {tuple(position)} is inside the shadow sphere of '
                         f'radius {radius} m')
    forward /= distance
    helper = np.array([0.0, 0.0, 1.0]) if abs(forward[1]) > 0.9 else np.array([0.0, 1.0, 0.0])
    right = np.cross(helper, forward)
    right /= np.linalg.norm(right)
    rotation = np.stack([right, np.cross(forward, right), forward])
    focal = SHADOW_MAP_SIZE / 2 / math.tan(math.asin(radius / distance))
    centre = (SHADOW_MAP_SIZE - 1) / 2
    view = CameraIntrinsics(focal, focal, centre, centre, SHADOW_MAP_SIZE, SHADOW_MAP_SIZE)
    extrinsic = np.eye(4)
    extrinsic[:3, :3] = rotation
    extrinsic[:3, 3] = -rotation @ position
    near = max(distance - radius, 1e-3)
    return opengl_projection(view, near, distance + radius) @ extrinsic
