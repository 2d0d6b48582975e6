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
Crops of table-top scenes: what the estimator would cut from LM-O-like frames.

``CropScenes`` renders each crop alone around a floating object; here a whole
``TableScenes`` frame is rendered (objects resting among clutter, shadows, highlights,
camera effects) and every target in it at least ``min_visib`` visible gives a crop, cut
from the frame around its jittered amodal box with ``extract_crops``, as the pipeline cuts
real frames. With ``dense_size`` M > 0 a second, unlit pass per crop renders the scene's
meshes through the crop's square at twice the crop size (``CameraIntrinsics.cropped``) and
reduces the target's model coordinates, visible and amodal silhouettes to the dense head's
M x M targets (``dense_targets``), exactly as ``CropScenes`` does.
"""

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from bbpose_ros.core.data.models import ObjectModel
from bbpose_ros.core.geometry.boxes import jitter_boxes
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.dense_grid import model_box
from bbpose_ros.core.nets.crops import extract_crops, square_boxes
from bbpose_ros.core.render import Lighting, MeshRenderer
from bbpose_ros.core.synth.backgrounds import PhotoBackgrounds
from bbpose_ros.core.synth.config import STORED_CROP_SIZE
from bbpose_ros.core.synth.crop_scenes import checked_dense_size, CropSample, in_frame_mask
from bbpose_ros.core.synth.dense_targets import dense_targets
from bbpose_ros.core.synth.table_config import TableConfig
from bbpose_ros.core.synth.table_scenes import TableScenes

# The coordinate pass reads only model coordinates and ids: any light will do.
_UNLIT = Lighting(ambient=1.0, diffuse=0.0)


class TableCrops:
    """
    A deterministic, endless source of table-top crops (``crops(index)``: scene ``index``).

    Args:
        models: {name: ObjectModel} targets.
        camera: CameraIntrinsics of the full frames.
        seed: non-negative int; scene ``index`` depends on (seed, index) only.
        config: TableConfig of the scenes (default settings when None).
        distractor_models: {name: ObjectModel} other meshes, unlabelled clutter.
        backgrounds: PhotoBackgrounds for the table, wall and background textures.
        crop_size: side S of the stored crops in pixels.
        context: crop side / longest side of the jittered box (the networks' ``context``).
        box_sigma: per-side box jitter / box size (``geometry.boxes.jitter_boxes``).
        min_visib: smallest visible fraction of a target that gives a crop.
        dense_size: side M of the dense targets' grid (0: none); ``2 crop_size`` must be a
            multiple of it.
        stable_pose_cache: folder of the cached stable poses (``TableScenes``).

    """

    def __init__(self, models: Mapping[str, ObjectModel], camera: CameraIntrinsics,
                 seed: int = 0, config: TableConfig | None = None,
                 distractor_models: Mapping[str, ObjectModel] | None = None,
                 backgrounds: PhotoBackgrounds | None = None,
                 crop_size: int = STORED_CROP_SIZE,
                 context: float = 1.2, box_sigma: float = 0.05, min_visib: float = 0.15,
                 dense_size: int = 0, stable_pose_cache: Path | str | None = None) -> None:
        self.dense_size = checked_dense_size(dense_size, crop_size)
        self.scenes = TableScenes(models, camera, seed, config, distractor_models,
                                  backgrounds, stable_pose_cache)
        self.camera, self.seed = camera, self.scenes.seed
        self.config, self.backgrounds = self.scenes.config, backgrounds
        self.target_names = self.scenes.target_names
        self.crop_size, self.context = int(crop_size), context
        self.box_sigma, self.min_visib = box_sigma, min_visib
        self.model_boxes = {name: model_box(model.vertices) for name, model in models.items()}
        self.render_size = 2 * self.crop_size
        self.crop_renderer = MeshRenderer(camera.cropped((0.0, 0.0, 1.0, 1.0), self.render_size),
                                          self.scenes.renderer.meshes)

    def close(self) -> None:
        """Release both renderers' GL contexts in this process."""
        self.scenes.close()
        self.crop_renderer.close()

    def crops(self, index: int) -> list[CropSample]:
        """Render scene ``index`` (non-negative int); return a crop per visible target."""
        sample, layout = self.scenes.sample_with_layout(index)
        instances = [i for i in sample.instances if i.visib_fract >= self.min_visib]
        if not instances:
            return []
        rng = np.random.default_rng([self.seed, 4, int(index)])
        boxes = np.stack([i.box_uv for i in instances])
        input_boxes = jitter_boxes(boxes, rng, self.box_sigma)
        squares = square_boxes(input_boxes, self.context)
        images = extract_crops(sample.image_rgb, squares, self.crop_size)
        keys = [mesh.key for mesh in layout.meshes]
        crops = []
        for k, instance in enumerate(instances):
            dense = () if not self.dense_size else self._dense(
                layout, keys.index(f'target/{instance.object_name}'), squares[k],
                instance.object_name)
            crops.append(CropSample(images[k], instance.object_name, instance.rotation,
                                    instance.translation, boxes[k], input_boxes[k],
                                    squares[k], instance.visib_fract, *dense))
        return crops

    def _dense(self, layout, draw_index, square, name):
        """Return the dense targets of draw ``draw_index`` over ``square`` (``dense_targets``)."""
        crop_camera = self.camera.cropped(square, self.render_size)
        rendered = self.crop_renderer.render(layout.draws, _UNLIT, (draw_index,), crop_camera,
                                             coordinates=True)
        visible = (rendered.instance_ids == draw_index + 1) & \
            in_frame_mask(self.camera, square, self.render_size)
        return dense_targets(rendered.model_coordinates, visible,
                             rendered.full_masks[draw_index], self.dense_size,
                             *self.model_boxes[name])
