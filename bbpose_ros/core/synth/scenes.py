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
Synthetic training scenes with exact ground truth.

Random poses of target meshes among distractors, rendered on random backgrounds.

Sample ``index`` of seed ``seed`` is always the same image: its random generator is seeded
with (seed, index) only, so samples can be drawn in any order, by any number of workers.
"""

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from bbpose_ros.core.data.models import ObjectModel
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.projection import projected_box_uv
from bbpose_ros.core.render import Draw, Lighting, MeshRenderer, RenderMesh, RenderResult
from bbpose_ros.core.synth.backgrounds import PhotoBackgrounds, random_background
from bbpose_ros.core.synth.config import SynthConfig
from bbpose_ros.core.synth.effects import apply_camera_effects
from bbpose_ros.core.synth.placement import pose_at_pixel, random_allocentric_rotation, \
    random_pixel
from bbpose_ros.core.synth.shapes import random_shape
from bbpose_ros.core.util.errors import InputError

# Closest a mesh's bounding sphere may come to the camera plane (metres).
_MIN_DEPTH = 0.05
# Attempts at a pose in front of the camera before giving up on an object.
_POSE_ATTEMPTS = 20
# Closest distance of a distractor to the camera (metres).
_MIN_DISTRACTOR_DISTANCE = 0.25


@dataclass(frozen=True)
class SynthInstance:
    """
    Ground truth of one target object in a synthetic image.

    Attributes:
        object_name: name of the object model, e.g. 'ape'.
        rotation: (3, 3) model-to-camera rotation, x_cam = R x_model + t.
        translation: (3,) model origin in the camera frame, metres.
        box_uv: (4,) amodal box [u_min, v_min, u_max, v_max]: extremes of the projected
            model vertices in continuous pixels (OpenCV convention); may leave the image.
        visib_fract: visible pixels / pixels of the unoccluded silhouette (parts outside the
            image count as hidden, as in BOP), in [0, 1].
        mask: (H, W) bool visible pixels of the object.

    """

    object_name: str
    rotation: np.ndarray
    translation: np.ndarray
    box_uv: np.ndarray
    visib_fract: float
    mask: np.ndarray


@dataclass(frozen=True)
class SyntheticSample:
    """
    One synthetic image and its ground truth.

    Attributes:
        image_rgb: (H, W, 3) uint8 RGB image.
        camera: the ``CameraIntrinsics`` it was rendered with.
        instances: tuple of ``SynthInstance``, one per target object with at least one
            visible pixel.

    """

    image_rgb: np.ndarray
    camera: CameraIntrinsics
    instances: tuple[SynthInstance, ...]


@dataclass(frozen=True)
class _Placed:
    """A placed mesh: its renderer key, pose, pixel of its origin and distance."""

    key: str
    rotation: np.ndarray
    translation: np.ndarray
    uv: np.ndarray
    distance: float


class SyntheticScenes:
    """
    A deterministic, endless source of synthetic scenes of some object models.

    ``models`` {name: ObjectModel} are the targets (labelled); ``distractor_models`` {name:
    ObjectModel} are other meshes that appear unlabelled, next to random primitive shapes.
    ``camera`` is a ``CameraIntrinsics``; ``seed`` a non-negative int; ``config`` a
    ``SynthConfig`` (default settings when None); ``backgrounds`` a ``PhotoBackgrounds``
    (None: procedural backgrounds only). The renderer is made lazily, in the
    process that draws the first sample, so instances may be passed to worker processes.
    """

    def __init__(self, models: Mapping[str, ObjectModel], camera: CameraIntrinsics,
                 seed: int = 0, config: SynthConfig | None = None,
                 distractor_models: Mapping[str, ObjectModel] | None = None,
                 backgrounds: PhotoBackgrounds | None = None) -> None:
        distractor_models = checked_scene_inputs(models, distractor_models, seed,
                                                 'synthetic scenes')
        self.camera = camera
        self.seed = int(seed)
        self.config = config if config is not None else SynthConfig()
        self.backgrounds = backgrounds
        self.target_names = list(models)
        meshes = scene_meshes(models, distractor_models, self.seed,
                              self.config.shape_size_range, self.config.shape_count)
        self.distractor_keys = [key for key in meshes if not key.startswith('target/')]
        self.radius = {key: float(np.linalg.norm(mesh.hull_points, axis=1).max())
                       for key, mesh in meshes.items()}
        self.hulls = {key: mesh.hull_points for key, mesh in meshes.items()}
        self.renderer = MeshRenderer(camera, meshes)

    def close(self) -> None:
        """Release the renderer's GL context in this process."""
        self.renderer.close()

    def sample(self, index: int) -> SyntheticSample:
        """Render sample number ``index`` (a non-negative int) as a SyntheticSample."""
        if int(index) != index or index < 0:
            raise InputError(f'sample index must be a non-negative integer, got {index}')
        config = self.config
        rng = np.random.default_rng([self.seed, 1, int(index)])
        targets = self._place_targets(rng)
        distractors = self._place_distractors(rng, targets)
        draws = [Draw(p.key, p.rotation, p.translation,
                      tuple(rng.uniform(*config.color_gain_range, 3)))
                 for p in targets + distractors]
        direction = rng.normal(size=3)
        direction[2] = -abs(direction[2])  # light from the camera's side of the scene
        lighting = Lighting(tuple(direction / np.linalg.norm(direction)),
                            rng.uniform(*config.ambient_range),
                            rng.uniform(*config.diffuse_range))
        rendered = self.renderer.render(draws, lighting, range(len(targets)))
        image = random_background(rng, self.camera.height, self.camera.width,
                                  self.backgrounds)
        covered = rendered.instance_ids > 0
        image[covered] = rendered.rgb[covered]
        image = apply_camera_effects(rng, image, config)
        return SyntheticSample(image, self.camera, visible_instances(
            rendered, draws, range(len(targets)), self.camera, self.hulls))

    def _box(self, placed):
        return projected_box_uv(self.camera, self.hulls[placed.key], placed.rotation,
                                placed.translation)

    def _place(self, rng, key, choose_uv_distance):
        """Place mesh ``key`` where ``choose_uv_distance(rng)`` says, in front of the camera."""
        for _ in range(_POSE_ATTEMPTS):
            uv, distance = choose_uv_distance(rng)
            rotation_allo = random_allocentric_rotation(rng, self.config.elevation_range_deg,
                                                        self.config.inplane_range_deg)
            rotation, translation = pose_at_pixel(self.camera, uv, distance, rotation_allo)
            if translation[2] - self.radius[key] > _MIN_DEPTH:
                return _Placed(key, rotation, translation, uv, distance)
        return None

    def _random_uv_distance(self, rng, distance_range):
        return (random_pixel(rng, self.camera, self.config.frame_margin),
                rng.uniform(*distance_range))

    def _place_targets(self, rng):
        """Choose distinct target objects and place them, some next to earlier ones."""
        config = self.config
        count = min(int(rng.integers(config.targets_per_image[0],
                                     config.targets_per_image[1] + 1)), len(self.target_names))
        placed = []
        for name_index in rng.choice(len(self.target_names), count, replace=False):
            key = f'target/{self.target_names[name_index]}'
            if placed and rng.random() < config.cluster_probability:
                anchor = placed[rng.integers(len(placed))]
                box = self._box(anchor)
                size = box[2:] - box[:2]

                def near_anchor(rng, anchor=anchor, size=size):
                    return (anchor.uv + rng.uniform(-0.6, 0.6, 2) * size,
                            float(np.clip(anchor.distance + rng.uniform(-0.15, 0.15),
                                          *config.distance_range)))
                result = self._place(rng, key, near_anchor)
            else:
                result = self._place(rng, key, lambda rng: self._random_uv_distance(
                    rng, config.distance_range))
            if result is not None:
                placed.append(result)
        return placed

    def _place_distractors(self, rng, targets):
        """Place random distractors, some in front of a target to hide part of it."""
        config = self.config
        count = int(rng.integers(config.distractors_per_image[0],
                                 config.distractors_per_image[1] + 1))
        placed = []
        for _ in range(count):
            key = self.distractor_keys[rng.integers(len(self.distractor_keys))]
            anchor = targets[rng.integers(len(targets))] if targets else None
            occluding = anchor is not None and rng.random() < config.occluder_probability
            far = anchor.distance - self.radius[anchor.key] - self.radius[key] \
                if occluding else 0.0
            if occluding and far > _MIN_DISTRACTOR_DISTANCE:
                box = self._box(anchor)
                size = box[2:] - box[:2]

                def in_front(rng, anchor=anchor, size=size, far=far):
                    return (anchor.uv + rng.uniform(-0.5, 0.5, 2) * size,
                            rng.uniform(_MIN_DISTRACTOR_DISTANCE, far))
                result = self._place(rng, key, in_front)
            else:
                result = self._place(rng, key, lambda rng: self._random_uv_distance(
                    rng, (_MIN_DISTRACTOR_DISTANCE, config.distance_range[1])))
            if result is not None:
                placed.append(result)
        return placed


def checked_scene_inputs(models: Mapping[str, ObjectModel],
                         distractor_models: Mapping[str, ObjectModel] | None, seed: int,
                         what: str) -> dict[str, ObjectModel]:
    """
    Check the targets, distractors and seed of a scene source (``what``, for the errors).

    Returns the distractors as a dict (empty for None); raises InputError without targets,
    with an object both target and distractor, or with a seed that is not an int >= 0.
    """
    if not models:
        raise InputError(f'{what} need at least one target object model')
    distractor_models = dict(distractor_models or {})
    shared = sorted(set(models) & set(distractor_models))
    if shared:
        raise InputError(f'objects cannot be both targets and distractors: '
                         f'{", ".join(shared)}')
    if int(seed) != seed or seed < 0:
        raise InputError(f'seed must be a non-negative integer, got {seed}')
    return distractor_models


def scene_meshes(models: Mapping[str, ObjectModel], distractor_models: Mapping[str, ObjectModel],
                 seed: int, shape_size_range: tuple[float, float],
                 shape_count: int) -> dict[str, RenderMesh]:
    """
    Make the meshes of a scene source, by renderer key.

    'target/NAME' for ``models``, 'distractor/NAME' for ``distractor_models`` and 'shape/i'
    for ``shape_count`` random shapes ``shape_size_range`` metres across, drawn from (seed,
    0) so that every process of one seed makes the same shapes.
    """
    meshes = {f'target/{name}': RenderMesh.from_object_model(model)
              for name, model in models.items()}
    meshes.update({f'distractor/{name}': RenderMesh.from_object_model(model)
                   for name, model in distractor_models.items()})
    shape_rng = np.random.default_rng([seed, 0])
    meshes.update({f'shape/{i}': random_shape(shape_rng, shape_size_range)
                   for i in range(shape_count)})
    return meshes


def visible_instances(rendered: RenderResult, draws: Sequence[Draw], targets: Iterable[int],
                      camera: CameraIntrinsics,
                      hulls: Mapping[str, np.ndarray]) -> tuple[SynthInstance, ...]:
    """
    Collect the ground truth of the target draws ``targets`` (indices) that show a pixel.

    ``rendered`` is the image's render (its full pixel counts include every target);
    a target draw's mesh key is 'target/NAME'; ``hulls`` {key: (N, 3) hull points} give the
    amodal boxes.
    """
    instances = []
    for i in targets:
        mask = rendered.instance_ids == i + 1
        visible = int(np.count_nonzero(mask))
        if visible == 0:
            continue
        draw = draws[i]
        instances.append(SynthInstance(
            object_name=draw.mesh.split('/', 1)[1], rotation=draw.rotation,
            translation=draw.translation,
            box_uv=projected_box_uv(camera, hulls[draw.mesh], draw.rotation, draw.translation),
            visib_fract=min(visible / rendered.full_pixel_counts[i], 1.0), mask=mask))
    return tuple(instances)
