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
Table-top training scenes like LM-O's: objects resting among clutter, lit with shadows.

As in BOP's physically based training images (objects dropped onto a plane in a room), the
meshes rest on a textured table in stable poses, close together so that they hide each
other, among clutter (other meshes, random shapes), in front of a textured wall, lit by
ambient light and point lights that cast shadows and make highlights; a camera looks down
at them from LM-O-like distances and elevations (``TableConfig``), then the image gets a
camera's colour response, blur, noise and JPEG artefacts.

Where the meshes rest and the camera stands is ``table_layout``'s (world frame: the table
is z = 0, z up); here the scene is lit, textured and rendered. Ground truth is exact, as in
``SyntheticScenes``: amodal boxes projected from the hulls, visible fractions from the
rendered instance ids over the full silhouettes.

Sample ``index`` of seed ``seed`` depends on (seed, index) only.
"""

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from bbpose_ros.core.data.models import ObjectModel
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.render import MeshRenderer
from bbpose_ros.core.render.gl_renderer import Draw
from bbpose_ros.core.render.scene_light import Material, PointLight, SceneLights, \
    TexturedPlane
from bbpose_ros.core.synth.backgrounds import PhotoBackgrounds, random_background
from bbpose_ros.core.synth.effects import apply_camera_effects, color_response
from bbpose_ros.core.synth.scenes import checked_scene_inputs, scene_meshes, \
    SyntheticSample, visible_instances
from bbpose_ros.core.synth.stable_poses import load_stable_poses, StablePoses, yaw_rotation
from bbpose_ros.core.synth.table_config import TableConfig
from bbpose_ros.core.synth.table_layout import draw_camera_pose, in_disc, place_meshes, \
    PlacedMesh, TableLayout
from bbpose_ros.core.util.errors import InputError

# Closest any mesh point may come to the camera plane (metres).
_MIN_DEPTH = 0.1
# Side of the table and wall textures (pixels).
_TEXTURE_SIZE = 512
# Half extents of a wall (metres): wide and high enough to fill the view behind the table.
_WALL_HALF_SIZE = (2.5, 1.5)


class TableScenes:
    """
    A deterministic, endless source of table-top scenes (``sample(index)``).

    The renderer is made lazily in the process that draws the first sample, so instances
    may be passed to worker processes.

    Args:
        models: {name: ObjectModel} targets (labelled).
        camera: CameraIntrinsics of the images.
        seed: non-negative int; sample ``index`` depends on (seed, index) only.
        config: TableConfig (default settings when None).
        distractor_models: {name: ObjectModel} other meshes, unlabelled clutter.
        backgrounds: PhotoBackgrounds for the table, wall and background textures (None:
            procedural textures only).
        stable_pose_cache: folder of the cached stable poses (default
            ``stable_poses.default_cache_dir()``).

    """

    def __init__(self, models: Mapping[str, ObjectModel], camera: CameraIntrinsics,
                 seed: int = 0, config: TableConfig | None = None,
                 distractor_models: Mapping[str, ObjectModel] | None = None,
                 backgrounds: PhotoBackgrounds | None = None,
                 stable_pose_cache: Path | str | None = None) -> None:
        distractor_models = checked_scene_inputs(models, distractor_models, seed,
                                                 'table scenes')
        self.camera, self.seed = camera, int(seed)
        self.config = config if config is not None else TableConfig()
        self.backgrounds = backgrounds
        self.target_names = list(models)
        meshes = scene_meshes(models, distractor_models, self.seed,
                              self.config.shape_size_range, self.config.shape_count)
        self.clutter_keys = [key for key in meshes if not key.startswith('target/')]
        self.hulls = {key: mesh.hull_points for key, mesh in meshes.items()}
        self.stable: dict[str, StablePoses] = {
            key: load_stable_poses(key.replace('/', '_'), mesh.vertices, mesh.faces,
                                   stable_pose_cache)
            for key, mesh in meshes.items()}
        self.renderer = MeshRenderer(camera, meshes)

    def close(self) -> None:
        """Release the renderer's GL context in this process."""
        self.renderer.close()

    def sample(self, index: int) -> SyntheticSample:
        """Render sample number ``index`` (a non-negative int) as a SyntheticSample."""
        return self.sample_with_layout(index)[0]

    def sample_with_layout(self, index: int, world_to_camera: np.ndarray | None = None,
                           shifted: Mapping[str, tuple[float, float]] | None = None
                           ) -> tuple[SyntheticSample, TableLayout]:
        """
        Render sample ``index``; return it and its ``TableLayout``.

        ``world_to_camera``: a (4, 4) camera pose (table frame, metres) to see the scene
        from instead of the sample's own (``camera_pose``): the same table, objects, lights,
        textures and camera effects seen from elsewhere, e.g. along a ``camera_path``; no
        wall then (a moving camera may pass where it stands). ``shifted``: {target object
        name: (dx, dy) metres}: those objects moved on the table, the rest of the scene as
        it was (a robot's object moved between two looks); what they then overlap is not
        checked.
        """
        config = self.config
        rng, radius, placed, drawn = self._scene(index)
        if shifted:
            placed = [PlacedMesh(mesh.key, mesh.rotation, mesh.translation + [
                *shifted.get(mesh.key.removeprefix('target/'), (0.0, 0.0)), 0.0])
                if mesh.key.startswith('target/') else mesh for mesh in placed]
        moved = world_to_camera is not None
        world_to_camera = np.asarray(world_to_camera) if moved else drawn
        rotation_wc, translation_wc = world_to_camera[:3, :3], world_to_camera[:3, 3]
        # Seen from elsewhere, every mesh draws its colours and material, seen or not, so
        # that the random stream, and with it the scene, is the same from every pose.
        gains = [self._color_gains(rng) for _ in placed] if moved else None
        draws, kept = [], []
        for k, mesh in enumerate(placed):
            rotation = rotation_wc @ mesh.rotation
            translation = rotation_wc @ mesh.translation + translation_wc
            if (self.hulls[mesh.key] @ rotation.T + translation)[:, 2].min() < _MIN_DEPTH:
                continue
            draws.append(Draw(mesh.key, rotation, translation,
                              gains[k] if moved else self._color_gains(rng)))
            kept.append(k)
        if moved:
            materials = [self._material(rng) for _ in placed]
            materials = [materials[k] for k in kept]
        else:
            materials = [self._material(rng) for _ in draws]
        kept = [placed[k] for k in kept]
        targets = [i for i, mesh in enumerate(kept) if mesh.key.startswith('target/')]
        if not config.clutter:
            # Drawn, then left out: the same scene otherwise (the random stream is kept).
            draws, kept, materials = ([items[i] for i in targets]
                                      for items in (draws, kept, materials))
            targets = list(range(len(targets)))
        lights = self._lights(rng, world_to_camera, radius)
        planes = self._planes(rng, world_to_camera, radius, drawn, wall=not moved)
        rendered = self.renderer.render_lit(draws, lights, materials, planes, targets)
        image = random_background(rng, self.camera.height, self.camera.width,
                                  self.backgrounds)
        image[rendered.covered] = rendered.rgb[rendered.covered]
        image = color_response(rng, image, config.white_balance_range, config.gamma_range)
        image = apply_camera_effects(rng, image, config.effects)
        instances = visible_instances(rendered, draws, targets, self.camera, self.hulls)
        return (SyntheticSample(image, self.camera, instances),
                TableLayout(tuple(kept), world_to_camera, tuple(draws)))

    def camera_pose(self, index: int) -> np.ndarray:
        """Return the (4, 4) world-to-camera pose sample ``index`` is seen from (metres)."""
        return self._scene(index)[3]

    def _scene(self, index):
        """
        Draw sample ``index``'s layout and camera.

        Returns:
            (its random stream, drawn so far; cluster radius, metres; PlacedMeshes; (4, 4)
            world-to-camera).

        """
        if int(index) != index or index < 0:
            raise InputError(f'sample index must be a non-negative integer, got {index}')
        rng = np.random.default_rng([self.seed, 3, int(index)])
        radius = rng.uniform(*self.config.cluster_radius_range)
        placed = place_meshes(rng, radius, self.config, self.target_names, self.clutter_keys,
                              self.hulls, self.stable)
        return rng, radius, placed, draw_camera_pose(rng, radius, self.config)

    def _color_gains(self, rng):
        """
        (r, g, b) linear factors on one mesh's 0..1 RGB colours.

        A log-uniform brightness times uniform per-channel gains; a fixed brightness range
        draws nothing, so the default (1, 1) keeps the random stream of configs without it.
        """
        config = self.config
        brightness = _log_uniform(rng, config.brightness_range)
        return tuple(brightness * rng.uniform(*config.color_gain_range, 3))

    def _material(self, rng):
        return Material(float(rng.uniform(*self.config.specular_range)),
                        _log_uniform(rng, self.config.shininess_range))

    def _lights(self, rng, world_to_camera, radius):
        """Make ambient light and point lights above the table, in the camera frame."""
        config = self.config
        lights = []
        for _ in range(int(rng.integers(config.lights_per_image[0],
                                        config.lights_per_image[1] + 1))):
            side = in_disc(rng, config.light_spread)
            position = np.array([side[0], side[1], rng.uniform(*config.light_height_range)])
            tint = rng.uniform(0.9, 1.1, 3)
            lights.append(PointLight(tuple(_to_camera(world_to_camera, position)),
                                     tuple(rng.uniform(*config.light_range) * tint)))
        ambient = rng.uniform(*config.ambient_range) * rng.uniform(0.95, 1.05, 3)
        # The shadow sphere holds the cluster and its tallest meshes.
        center = _to_camera(world_to_camera, np.array([0.0, 0.0, 0.1]))
        return SceneLights(tuple(lights), tuple(ambient), tuple(center), radius + 0.3,
                           config.shadows)

    def _planes(self, rng, world_to_camera, radius, drawn, wall=True):
        """
        Make the table, and maybe a wall, in the camera frame of ``world_to_camera``.

        The wall stands behind the cluster as seen from the sample's ``drawn`` camera; it is
        drawn (the random stream) but left out without ``wall``.
        """
        config = self.config
        rotation_wc = world_to_camera[:3, :3]
        table_rotation = rotation_wc @ yaw_rotation(rng.uniform(0.0, 2.0 * np.pi))
        half = rng.uniform(*config.table_half_size_range, 2)
        half = np.maximum(half, radius + 0.1)
        planes = [TexturedPlane(table_rotation, _to_camera(world_to_camera, np.zeros(3)),
                                tuple(half), self._texture(rng),
                                float(rng.uniform(*config.texture_tile_range)),
                                self._material(rng))]
        if rng.random() < config.wall_probability:
            # Behind the cluster as the camera sees it: opposite the camera, +-45 deg.
            camera_position = -drawn[:3, :3].T @ drawn[:3, 3]
            away = np.arctan2(-camera_position[1], -camera_position[0]) + \
                rng.uniform(-np.pi / 4, np.pi / 4)
            normal = -np.array([np.cos(away), np.sin(away), 0.0])    # towards the cluster
            along = np.array([-normal[1], normal[0], 0.0])
            up = np.array([0.0, 0.0, 1.0])
            wall_rotation = np.stack([along, np.cross(normal, along), normal], axis=1)
            centre = -normal * rng.uniform(*config.wall_distance_range) + \
                up * _WALL_HALF_SIZE[1]
            plane = TexturedPlane(rotation_wc @ wall_rotation,
                                  _to_camera(world_to_camera, centre), _WALL_HALF_SIZE,
                                  self._texture(rng),
                                  float(rng.uniform(*config.texture_tile_range)),
                                  self._material(rng))
            if wall:
                planes.append(plane)
        return planes

    def _texture(self, rng):
        return random_background(rng, _TEXTURE_SIZE, _TEXTURE_SIZE, self.backgrounds)


def _log_uniform(rng, low_high):
    """Draw a float log-uniformly from ``(low, high)``, both > 0 (``low == high``: no draw)."""
    low, high = low_high
    if low == high:
        return float(low)
    return float(np.exp(rng.uniform(np.log(low), np.log(high))))


def _to_camera(world_to_camera, point):
    return world_to_camera[:3, :3] @ point + world_to_camera[:3, 3]
