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
Writing synthetic samples in the BOP format (readable by ``bbpose_ros.core.data.bop``).

Layout under ``root``: ``camera.json`` and ``<split>/<scene:06d>/`` with ``rgb/`` (PNG),
``mask_visib/`` (PNG per instance), ``scene_gt.json`` (rotation, translation in mm),
``scene_camera.json`` and ``scene_gt_info.json``. BOP's integer boxes (x, y, w, h) follow the
convention of ``bop_box_to_uv``; the exact continuous boxes are kept in the extra fields
``box_uv`` and ``visible_box_uv`` ([u_min, v_min, u_max, v_max], OpenCV pixel convention).
"""

from collections.abc import Mapping, Sequence
import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from bbpose_ros.core.data.bop import bop_camera_fields
from bbpose_ros.core.data.models import MM_TO_M
from bbpose_ros.core.geometry.boxes import mask_box_uv
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.rigid import invert_rigid
from bbpose_ros.core.synth.scenes import SyntheticSample
from bbpose_ros.core.util.files import write_rgb_png


def uv_to_bop_box(box_uv: Sequence[float] | np.ndarray) -> list[int]:
    """
    Convert to an integer BOP box [x, y, w, h] a continuous box [u_min, v_min, u_max, v_max].

    The inverse of ``bop_box_to_uv`` (x = u_min, x + w + 1 = u_max) up to rounding.
    """
    x, y = round(float(box_uv[0])), round(float(box_uv[1]))
    return [x, y, max(round(float(box_uv[2])) - x - 1, 0),
            max(round(float(box_uv[3])) - y - 1, 0)]


def camera_json(camera: CameraIntrinsics) -> dict[str, float]:
    """Return the BOP ``camera.json`` fields of a CameraIntrinsics."""
    return {'fx': camera.fx, 'fy': camera.fy, 'cx': camera.cx, 'cy': camera.cy,
            'width': camera.width, 'height': camera.height, 'depth_scale': 1.0}


def write_json(path: Path | str, data: Any) -> None:
    """Write ``data`` as indented JSON to ``path``."""
    Path(path).write_text(json.dumps(data, indent=1) + '\n')


class BopSceneWriter:
    """
    Collects samples into one BOP scene folder; ``finish`` writes the JSON files.

    ``obj_ids`` maps object names to BOP object ids.
    """

    def __init__(self, root: Path | str, camera: CameraIntrinsics, obj_ids: Mapping[str, int],
                 split: str = 'train_synth', scene_id: int = 0) -> None:
        self.root = Path(root)
        self.camera = camera
        self.obj_ids = dict(obj_ids)
        self.scene_dir = self.root / split / f'{scene_id:06d}'
        (self.scene_dir / 'rgb').mkdir(parents=True)
        self.scene_gt, self.scene_camera, self.scene_gt_info = {}, {}, {}

    def add(self, image_id: int, sample: SyntheticSample,
            world_to_camera: np.ndarray | None = None) -> None:
        """
        Write sample ``image_id`` (int)'s image and masks and record its ground truth.

        ``world_to_camera``: the (4, 4) camera pose it was rendered from (metres), written
        as BOP's ``cam_R_w2c`` / ``cam_t_w2c`` (a camera path's frames carry it).
        """
        (self.scene_dir / 'mask_visib').mkdir(exist_ok=True)
        infos = []
        for index, instance in enumerate(sample.instances):
            mask_path = self.scene_dir / 'mask_visib' / f'{image_id:06d}_{index:06d}.png'
            if not cv2.imwrite(str(mask_path), instance.mask.astype(np.uint8) * 255):
                raise OSError(f'cannot write mask {mask_path}')
            visible_box = mask_box_uv(instance.mask)
            infos.append({'bbox_visib': uv_to_bop_box(visible_box),
                          'px_count_visib': int(np.count_nonzero(instance.mask)),
                          'visib_fract': float(instance.visib_fract),
                          'visible_box_uv': visible_box.tolist()})
        self.add_poses(image_id, sample.image_rgb, sample.camera, sample.instances, infos)
        if world_to_camera is not None:
            self.scene_camera[str(image_id)].update(
                bop_camera_fields(invert_rigid(world_to_camera)))

    def add_poses(self, image_id: int, image_rgb: np.ndarray, camera: CameraIntrinsics,
                  poses: Sequence[Any], infos: Sequence[Mapping[str, Any]]) -> None:
        """
        Write image ``image_id`` (int) and record its poses and their amodal boxes.

        Each pose has ``object_name``, ``rotation`` (3, 3) model-to-camera, ``translation``
        (3,) metres and ``box_uv`` (4,) amodal box; ``infos`` adds its scene_gt_info fields
        (visibility, visible box, a confidence: whatever the source knows).
        """
        write_rgb_png(self.scene_dir / 'rgb' / f'{image_id:06d}.png', image_rgb)
        key = str(image_id)
        self.scene_gt[key] = [{'obj_id': self.obj_ids[pose.object_name],
                               'cam_R_m2c': np.asarray(pose.rotation).reshape(-1).tolist(),
                               'cam_t_m2c': (np.asarray(pose.translation) / MM_TO_M).tolist()}
                              for pose in poses]
        self.scene_gt_info[key] = [{'bbox_obj': uv_to_bop_box(pose.box_uv), **info,
                                    'box_uv': np.asarray(pose.box_uv).tolist()}
                                   for pose, info in zip(poses, infos)]
        self.scene_camera[key] = {'cam_K': camera.k.reshape(-1).tolist(), 'depth_scale': 1.0}

    def finish(self) -> None:
        """Write ``camera.json`` and the scene's JSON files."""
        write_json(self.root / 'camera.json', camera_json(self.camera))
        write_json(self.scene_dir / 'scene_gt.json', self.scene_gt)
        write_json(self.scene_dir / 'scene_gt_info.json', self.scene_gt_info)
        write_json(self.scene_dir / 'scene_camera.json', self.scene_camera)


def draw_preview(sample: SyntheticSample) -> np.ndarray:
    """Draw the amodal boxes and labels on an (H, W, 3) uint8 RGB copy of the image."""
    image = sample.image_rgb.copy()
    for instance in sample.instances:
        u0, v0, u1, v1 = (int(round(float(x))) for x in instance.box_uv)
        cv2.rectangle(image, (u0, v0), (u1, v1), (0, 255, 0), 1)
        cv2.putText(image, f'{instance.object_name} {instance.visib_fract:.2f}',
                    (u0, max(v0 - 3, 10)), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 255, 0), 1,
                    cv2.LINE_AA)
    return image
