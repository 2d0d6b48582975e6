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
Object-centred synthetic crops for Q-Net: the crop the estimator would cut, rendered directly.

Rendering whole 640x480 scenes on the CPU gives far too few views of SO(3) for Q-Net, which
then memorises them instead of generalising. A crop needs only a small image, so it renders
many times faster: the object is posed in the full camera exactly as in ``SyntheticScenes``
(pixel, distance, LM-O-like viewpoint), its amodal box is jittered as a detector would, and
only the square crop around that box is rendered, through ``CameraIntrinsics.cropped``.
Neighbouring meshes and occluders are posed in the same camera, the background is cut from
a full-frame procedural background or photograph at the crop's scale, camera effects are
applied at the crop's native resolution (a 40-pixel box stays blurry after resizing), and
parts outside the frame are grey, as ``extract_crops`` fills them.

With ``dense_size`` M > 0 each crop also carries the dense head's targets on an M x M grid
over the same square (``dense_targets``): the target's normalised model coordinates, its
visible share (occluders and the frame border hide) and its amodal share per cell.
"""

from collections.abc import Mapping
from dataclasses import dataclass

import cv2
import numpy as np

from bbpose_ros.core.data.models import ObjectModel
from bbpose_ros.core.geometry.boxes import jitter_boxes
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.dense_grid import model_box
from bbpose_ros.core.geometry.projection import projected_box_uv
from bbpose_ros.core.nets.crops import FILL_VALUE, square_boxes
from bbpose_ros.core.render import Draw, Lighting, MeshRenderer, RenderMesh
from bbpose_ros.core.synth.backgrounds import PhotoBackgrounds, random_background
from bbpose_ros.core.synth.config import STORED_CROP_SIZE, SynthConfig
from bbpose_ros.core.synth.dense_targets import dense_targets
from bbpose_ros.core.synth.effects import apply_camera_effects
from bbpose_ros.core.synth.placement import pose_at_pixel, random_allocentric_rotation, \
    random_pixel
from bbpose_ros.core.synth.shapes import random_shape
from bbpose_ros.core.util.errors import InputError

# Attempts at a sample with enough of the target visible before giving up.
_ATTEMPTS = 50
# Closest distance of any mesh to the camera (metres).
_MIN_DISTANCE = 0.25

# LM-O objects are rarely cut by the image border: crop centres stay 8 % inside it.
CROP_SYNTH_CONFIG = SynthConfig(frame_margin=-0.08)


def checked_dense_size(dense_size: int, crop_size: int) -> int:
    """Return ``dense_size`` as an int, checked: 0, or a divisor of the render size."""
    size = int(dense_size)
    if size < 0 or (size and 2 * int(crop_size) % size):
        raise InputError(f'dense_size {dense_size} must divide the render size '
                         f'{2 * int(crop_size)} (twice the crop size)')
    return size


def in_frame_mask(camera: CameraIntrinsics, square_uv: np.ndarray, size: int) -> np.ndarray:
    """
    (size, size) bool: the pixels of a render of ``square_uv`` whose centres lie in the frame.

    ``square_uv`` (4,) is a region of ``camera``'s full frame (continuous pixels) rendered at
    size x size pixels; parts of it beyond the frame's edges are what the camera never saw.
    """
    cols = square_uv[0] + (np.arange(size) + 0.5) * (square_uv[2] - square_uv[0]) / size
    rows = square_uv[1] + (np.arange(size) + 0.5) * (square_uv[3] - square_uv[1]) / size
    inside_u = (cols >= -0.5) & (cols <= camera.width - 0.5)
    inside_v = (rows >= -0.5) & (rows <= camera.height - 0.5)
    return inside_v[:, None] & inside_u[None, :]


@dataclass(frozen=True)
class CropSample:
    """
    One rendered Q-Net input and its ground truth.

    Attributes:
        image_rgb: (S, S, 3) uint8 crop of ``square_uv``.
        object_name: the target object, e.g. 'ape'.
        rotation: (3, 3) egocentric model-to-camera rotation (full camera).
        translation: (3,) metres, full camera frame.
        box_uv: (4,) amodal box in full-frame continuous pixels.
        input_box_uv: (4,) the jittered box the crop is centred on (a detector's output).
        square_uv: (4,) the square region of the full frame the crop shows.
        visib_fract: visible share of the target's silhouette (outside the frame = hidden).
        coordinates: (M, M, 3) float32 normalised model coordinates per grid cell, or None
            without dense targets (see ``dense_targets``).
        visible_mask: (M, M) float32 visible share of each cell, or None.
        amodal_mask: (M, M) float32 share of each cell the whole silhouette covers, or None.

    """

    image_rgb: np.ndarray
    object_name: str
    rotation: np.ndarray
    translation: np.ndarray
    box_uv: np.ndarray
    input_box_uv: np.ndarray
    square_uv: np.ndarray
    visib_fract: float
    coordinates: np.ndarray | None = None
    visible_mask: np.ndarray | None = None
    amodal_mask: np.ndarray | None = None


class CropScenes:
    """
    A deterministic, endless source of object-centred crops (``sample(index)``).

    Args:
        models: {name: ObjectModel} targets; sample ``index`` shows target
            ``index % len(models)``, so objects are balanced.
        camera: CameraIntrinsics of the full frames the crops are cut from.
        seed: non-negative int; sample ``index`` depends on (seed, index) only.
        config: SynthConfig (poses, clutter, light, camera effects).
        distractor_models: {name: ObjectModel} unlabelled meshes for clutter.
        crop_size: side S of the stored crops in pixels.
        context: crop side / longest side of the jittered box (Q-Net's ``context``).
        box_sigma: per-side box jitter / box size (``geometry.boxes.jitter_boxes``).
        min_visib: smallest visible fraction of the target kept.
        neighbours: (low, high) count of meshes placed around the target.
        backgrounds: PhotoBackgrounds, or None for procedural backgrounds only.
        dense_size: side M of the dense targets' grid (0: none); ``2 crop_size`` (the
            render size) must be a multiple of it.

    """

    def __init__(self, models: Mapping[str, ObjectModel], camera: CameraIntrinsics,
                 seed: int = 0, config: SynthConfig | None = None,
                 distractor_models: Mapping[str, ObjectModel] | None = None,
                 crop_size: int = STORED_CROP_SIZE, context: float = 1.2,
                 box_sigma: float = 0.05, min_visib: float = 0.15,
                 neighbours: tuple[int, int] = (0, 4),
                 backgrounds: PhotoBackgrounds | None = None, dense_size: int = 0) -> None:
        if not models:
            raise InputError('crop scenes need at least one target object model')
        if int(seed) != seed or seed < 0:
            raise InputError(f'seed must be a non-negative integer, got {seed}')
        self.camera, self.seed = camera, int(seed)
        self.config = config if config is not None else CROP_SYNTH_CONFIG
        self.target_names = list(models)
        self.crop_size, self.context, self.box_sigma = int(crop_size), context, box_sigma
        self.min_visib, self.neighbours = min_visib, neighbours
        self.backgrounds = backgrounds
        self.dense_size = checked_dense_size(dense_size, self.crop_size)
        self.model_boxes = {name: model_box(model.vertices) for name, model in models.items()}
        meshes = {f'target/{name}': RenderMesh.from_object_model(model)
                  for name, model in models.items()}
        meshes.update({f'distractor/{name}': RenderMesh.from_object_model(model)
                       for name, model in (distractor_models or {}).items()})
        shape_rng = np.random.default_rng([self.seed, 0])
        meshes.update({f'shape/{i}': random_shape(shape_rng, self.config.shape_size_range)
                       for i in range(self.config.shape_count)})
        self.clutter_keys = list(meshes)
        self.hulls = {key: mesh.hull_points for key, mesh in meshes.items()}
        self.radius = {key: float(np.linalg.norm(hull, axis=1).max())
                       for key, hull in self.hulls.items()}
        # Rendered at twice the crop size, then reduced: anti-aliased like a real crop.
        self.render_size = 2 * self.crop_size
        base = camera.cropped((0.0, 0.0, 1.0, 1.0), self.render_size)
        self.renderer = MeshRenderer(base, meshes)

    def close(self) -> None:
        """Release the renderer's GL context in this process."""
        self.renderer.close()

    def sample(self, index: int) -> CropSample:
        """Render crop number ``index`` (a non-negative int) as a CropSample."""
        if int(index) != index or index < 0:
            raise InputError(f'sample index must be a non-negative integer, got {index}')
        rng = np.random.default_rng([self.seed, 2, int(index)])
        name = self.target_names[index % len(self.target_names)]
        for _ in range(_ATTEMPTS):
            sample = self._attempt(rng, name)
            if sample is not None:
                return sample
        raise RuntimeError(f'no crop of {name} with visib_fract >= {self.min_visib} in '
                           f'{_ATTEMPTS} attempts (sample {index})')

    def crops(self, index: int) -> list[CropSample]:
        """Render crop number ``index`` as a one-crop list (the crop caches' interface)."""
        return [self.sample(index)]

    def _attempt(self, rng, name):
        config, camera = self.config, self.camera
        key = f'target/{name}'
        rotation, translation, uv, distance = self._pose(
            rng, key, random_pixel(rng, camera, config.frame_margin),
            rng.uniform(*config.distance_range))
        if rotation is None:
            return None
        box = projected_box_uv(camera, self.hulls[key], rotation, translation)
        input_box = jitter_boxes(box[None], rng, self.box_sigma)[0]
        square = square_boxes(input_box, self.context)[0]
        crop_camera = camera.cropped(square, self.render_size)
        draws = [Draw(key, rotation, translation,
                      tuple(rng.uniform(*config.color_gain_range, 3)))]
        draws += self._clutter(rng, key, uv, distance, box)
        direction = rng.normal(size=3)
        direction[2] = -abs(direction[2])  # light from the camera's side of the scene
        lighting = Lighting(tuple(direction / np.linalg.norm(direction)),
                            rng.uniform(*config.ambient_range),
                            rng.uniform(*config.diffuse_range))
        rendered = self.renderer.render(draws, lighting, (0,), crop_camera,
                                        coordinates=self.dense_size > 0)
        in_frame = in_frame_mask(camera, square, self.render_size)
        visible_mask = (rendered.instance_ids == 1) & in_frame
        visible = np.count_nonzero(visible_mask)
        visib = min(visible / max(rendered.full_pixel_counts[0], 1), 1.0)
        if visib < self.min_visib:
            return None
        image = self._background(rng, square[2] - square[0])
        covered = rendered.instance_ids > 0
        image[covered] = rendered.rgb[covered]
        image = self._as_camera_sees(rng, image, in_frame, square[2] - square[0])
        if not self.dense_size:
            return CropSample(image, name, rotation, translation, box, input_box, square, visib)
        dense = dense_targets(rendered.model_coordinates, visible_mask, rendered.full_masks[0],
                              self.dense_size, *self.model_boxes[name])
        return CropSample(image, name, rotation, translation, box, input_box, square, visib,
                          *dense)

    def _pose(self, rng, key, uv, distance):
        """Egocentric pose of mesh ``key`` seen through pixel ``uv`` at ``distance`` metres."""
        rotation_allo = random_allocentric_rotation(rng, self.config.elevation_range_deg,
                                                    self.config.inplane_range_deg)
        rotation, translation = pose_at_pixel(self.camera, uv, distance, rotation_allo)
        if translation[2] - self.radius[key] < _MIN_DISTANCE / 2:
            return None, None, None, None
        return rotation, translation, uv, distance

    def _clutter(self, rng, target_key, uv, distance, box):
        """Draws of meshes beside, behind and (``occluder_probability``) in front of the target."""
        config = self.config
        size = box[2:] - box[:2]
        placements = [(uv + rng.uniform(-0.9, 0.9, 2) * size,
                       distance + rng.uniform(-0.1, 0.3))
                      for _ in range(rng.integers(self.neighbours[0], self.neighbours[1] + 1))]
        if rng.random() < config.occluder_probability:
            far = distance - self.radius[target_key] - 0.05
            if far > _MIN_DISTANCE:
                placements.append((uv + rng.uniform(-0.6, 0.6, 2) * size,
                                   rng.uniform(_MIN_DISTANCE, far)))
        draws = []
        for other_uv, other_distance in placements:
            other = self.clutter_keys[rng.integers(len(self.clutter_keys))]
            rotation, translation, _, _ = self._pose(rng, other, other_uv,
                                                     max(other_distance, _MIN_DISTANCE))
            if rotation is not None:
                draws.append(Draw(other, rotation, translation,
                                  tuple(rng.uniform(*config.color_gain_range, 3))))
        return draws

    def _background(self, rng, side):
        """(R, R, 3) uint8 background of a crop of ``side`` full-frame pixels."""
        native = int(np.clip(round(side), 16, 2 * self.render_size))
        image = random_background(rng, native, native, self.backgrounds)
        return cv2.resize(image, (self.render_size,) * 2, interpolation=cv2.INTER_LINEAR)

    def _as_camera_sees(self, rng, image, in_frame, side):
        """Reduce to the crop's native resolution, apply camera effects, grey-fill, resize."""
        native = int(np.clip(round(side), 8, self.render_size))
        image = cv2.resize(image, (native, native), interpolation=cv2.INTER_AREA)
        image = apply_camera_effects(rng, image, self.config)
        outside = cv2.resize(np.uint8(~in_frame), (native, native),
                             interpolation=cv2.INTER_NEAREST) > 0
        image[outside] = FILL_VALUE
        interpolation = cv2.INTER_AREA if native > self.crop_size else cv2.INTER_LINEAR
        return cv2.resize(image, (self.crop_size, self.crop_size), interpolation=interpolation)
