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
Reader for datasets in the BOP format (github.com/thodan/bop_toolkit).

BOP stores translations in millimetres and boxes as integer (x, y, w, h) of the covered
pixels; this reader returns metres and continuous boxes (see ``bop_box_to_uv``).
"""

from collections.abc import Collection, Iterable
from dataclasses import dataclass
import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from bbpose_ros.core.data.models import fallback_object_name, load_bop_models, MM_TO_M, \
    object_names, ObjectModel
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.rigid import invert_rigid, is_rigid, rigid_matrix
from bbpose_ros.core.geometry.rotations import nearest_rotation
from bbpose_ros.core.util.errors import InputError


# Where the development frames live beside a checkout (overridden by --dataset and
# $BBPOSE_DATASET).
DEFAULT_DATASET = Path('../shared/datasets/lmo')


def bop_box_to_uv(bbox_xywh: npt.ArrayLike) -> np.ndarray:
    """
    Convert a BOP box (x, y, w, h) to a continuous box [x, y, x + w + 1, y + h + 1].

    BOP's box covers pixel columns x .. x + w inclusive, from a renderer whose pixel (i, j)
    spans [i, i + 1] x [j, j + 1] in K's coordinates. The projected model's extremes are
    therefore at u = x and u = x + w + 1.
    BOP writes (-1, -1, -1, -1) when it has no box; that becomes four NaNs.
    """
    x, y, w, h = (float(value) for value in bbox_xywh)
    if w < 0 or h < 0:
        return np.full(4, np.nan)
    return np.array([x, y, x + w + 1.0, y + h + 1.0])


@dataclass(frozen=True)
class GroundTruthInstance:
    """
    One annotated object instance in a frame.

    Attributes:
        object_name: e.g. 'ape'.
        obj_id: BOP object id.
        rotation: (3, 3) model-to-camera rotation (the stored matrix projected onto SO(3):
            ``nearest_rotation``).
        translation: (3,) metres, camera frame.
        box_uv: (4,) amodal box (whole projected model, hidden parts included),
            [u_min, v_min, u_max, v_max] continuous pixels; NaN when the annotation has
            none (``bbox_obj`` absent, or BOP's -1 for an object out of view).
        visible_box_uv: (4,) box of the visible pixels, same convention (NaN likewise).
        visib_fract: visible fraction of the projected object, 0..1.

    """

    object_name: str
    obj_id: int
    rotation: np.ndarray
    translation: np.ndarray
    box_uv: np.ndarray
    visible_box_uv: np.ndarray
    visib_fract: float


@dataclass(frozen=True)
class BopFrame:
    """
    One image of a BOP scene with its camera and ground truth.

    ``world_from_camera``: (4, 4) the camera's pose in the scene's world frame, metres,
    from BOP's optional ``cam_R_w2c`` / ``cam_t_w2c`` (world-to-camera, mm) in
    ``scene_camera.json``; None where the scene has none.
    """

    scene_id: int
    image_id: int
    image_path: Path
    camera: CameraIntrinsics
    instances: tuple[GroundTruthInstance, ...]
    world_from_camera: np.ndarray | None = None

    def load_image(self) -> np.ndarray:
        """Read the image as (H, W, 3) uint8 RGB; a missing or unreadable file is named."""
        image = cv2.imread(str(self.image_path), cv2.IMREAD_COLOR)
        if image is None:
            raise InputError(f'missing or unreadable image: {self.image_path}')
        if image.shape[:2] != (self.camera.height, self.camera.width):
            raise InputError(
                f'image {self.image_path} is {image.shape[1]}x{image.shape[0]}, but its camera '
                f'says {self.camera.width}x{self.camera.height}')
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def read_json(path: Path | str) -> Any:
    """Read a JSON file; a missing or malformed file is an InputError naming it."""
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except FileNotFoundError as err:
        raise InputError(f'missing file: {path}') from err
    except ValueError as err:
        raise InputError(f'malformed JSON in {path}: {err}') from err


def load_camera(dataset_dir: Path | str) -> CameraIntrinsics:
    """Read the CameraIntrinsics of a BOP dataset's ``camera.json``."""
    path = Path(dataset_dir) / 'camera.json'
    data = read_json(path)
    try:
        return CameraIntrinsics(float(data['fx']), float(data['fy']), float(data['cx']),
                                float(data['cy']), int(data['width']), int(data['height']))
    except (KeyError, TypeError, ValueError) as err:
        raise InputError(f'{path}: needs numeric fx, fy, cx, cy, width, height ({err})') from err


def _field(record, key, path, where, shape=None):
    """Fetch ``record[key]`` (as an array of ``shape`` if given) or name what is wrong."""
    try:
        value = record[key]
        return value if shape is None else np.asarray(value, dtype=float).reshape(shape)
    except (KeyError, TypeError, ValueError) as err:
        raise InputError(f'{path}: {where} has no valid "{key}" ({err})') from err


def _optional_box(info, key, scene_dir, where):
    """Read a scene_gt_info box as ``bop_box_to_uv`` gives it; an absent one is NaN."""
    if isinstance(info, dict) and key not in info:
        return np.full(4, np.nan)
    return bop_box_to_uv(_field(info, key, scene_dir / 'scene_gt_info.json', where, (4,)))


def _camera_pose(record, scene_dir, image_id):
    """world_from_camera (4, 4) metres of a scene_camera record, None without the fields."""
    if 'cam_R_w2c' not in record and 'cam_t_w2c' not in record:
        return None
    path, where = scene_dir / 'scene_camera.json', f'image {image_id}'
    rotation = _field(record, 'cam_R_w2c', path, where, (3, 3))
    translation = _field(record, 'cam_t_w2c', path, where, (3,)) * MM_TO_M
    camera_from_world = rigid_matrix(rotation, translation)
    if not is_rigid(camera_from_world, tolerance=1e-4):
        raise InputError(f'{path}: {where} has a cam_R_w2c / cam_t_w2c that is not a finite '
                         'rigid transform')
    return invert_rigid(camera_from_world)


def bop_camera_fields(world_from_camera: np.ndarray) -> dict[str, list[float]]:
    """Return BOP's ``cam_R_w2c`` (9,) and ``cam_t_w2c`` (3,) mm of a world_from_camera."""
    camera_from_world = invert_rigid(world_from_camera)
    return {'cam_R_w2c': camera_from_world[:3, :3].reshape(-1).tolist(),
            'cam_t_w2c': (camera_from_world[:3, 3] / MM_TO_M).tolist()}


def split_names(root: Path | str) -> list[str]:
    """Sorted names of a BOP folder's splits: its subfolders holding scene folders (NNNNNN)."""
    return sorted(path.name for path in Path(root).iterdir() if path.is_dir() and any(
        scene.is_dir() and scene.name.isdigit() for scene in path.iterdir()))


class BopDataset:
    """
    A BOP dataset folder: ``camera.json``, ``models/``, ``<split>/<scene>/`` per scene.

    Scenes hold ``rgb/``, ``scene_camera.json``, ``scene_gt.json`` and
    ``scene_gt_info.json``. Instances are named by the dataset's names table
    (``object_names``); an id it lacks gets ``fallback_object_name``.
    """

    def __init__(self, root: Path | str, split: str = 'test') -> None:
        self.root = Path(root)
        if not self.root.is_dir():
            raise InputError(f'dataset folder not found: {self.root}')
        self.split_dir = self.root / split
        if not self.split_dir.is_dir():
            found = ', '.join(split_names(self.root)) or 'none'
            raise InputError(f'dataset split folder not found: {self.split_dir} (splits in '
                             f'{self.root}: {found})')
        self.camera_size = self._image_size()
        self.names = object_names(self.root)

    def _image_size(self):
        camera_path = self.root / 'camera.json'
        camera = read_json(camera_path)
        return (int(_field(camera, 'width', camera_path, 'camera')),
                int(_field(camera, 'height', camera_path, 'camera')))

    @property
    def scene_ids(self) -> list[int]:
        """Sorted ids of the scenes in the split."""
        return sorted(int(p.name) for p in self.split_dir.iterdir()
                      if p.is_dir() and p.name.isdigit())

    def load_models(self, names: Collection[str] | None = None) -> dict[str, ObjectModel]:
        """Load the object models as {name: ObjectModel} (see ``load_bop_models``)."""
        return load_bop_models(self.root, names)

    def frames(self, scene_ids: Iterable[int] | None = None,
               image_ids: Collection[int] | None = None,
               ground_truth: bool = True) -> list[BopFrame]:
        """
        All frames of the given scenes (default all), sorted by scene and image id.

        ``image_ids`` optionally keeps only those image ids. Without ``ground_truth`` the
        scenes' ``scene_gt*.json`` are not read (they may be absent) and the frames have no
        instances: unlabelled images, as ``bbpose adapt`` takes them.
        """
        frames = []
        for scene_id in scene_ids if scene_ids is not None else self.scene_ids:
            frames.extend(self._scene_frames(scene_id, image_ids, ground_truth))
        return frames

    def _scene_frames(self, scene_id, image_ids, ground_truth):
        scene_dir = self.split_dir / f'{scene_id:06d}'
        cameras = read_json(scene_dir / 'scene_camera.json')
        gts = read_json(scene_dir / 'scene_gt.json') if ground_truth else {}
        infos = read_json(scene_dir / 'scene_gt_info.json') if ground_truth else {}
        width, height = self.camera_size
        frames = []
        for key in sorted(cameras, key=int):
            image_id = int(key)
            if image_ids is not None and image_id not in image_ids:
                continue
            k = _field(cameras[key], 'cam_K', scene_dir / 'scene_camera.json',
                       f'image {image_id}', (3, 3))
            camera = CameraIntrinsics.from_k(k, width, height)
            instances = self._instances(scene_dir, key, gts.get(key, []), infos.get(key, []),
                                        self.names)
            frames.append(BopFrame(scene_id, image_id, self._image_path(scene_dir, image_id),
                                   camera, instances,
                                   _camera_pose(cameras[key], scene_dir, image_id)))
        return frames

    @staticmethod
    def _image_path(scene_dir, image_id):
        for folder, ext in (('rgb', '.png'), ('rgb', '.jpg'), ('gray', '.png')):
            path = scene_dir / folder / f'{image_id:06d}{ext}'
            if path.is_file():
                return path
        return scene_dir / 'rgb' / f'{image_id:06d}.png'

    @staticmethod
    def _instances(scene_dir, key, gts, infos, names):
        if len(gts) != len(infos):
            raise InputError(f'{scene_dir}: image {key} has {len(gts)} poses in scene_gt.json '
                             f'but {len(infos)} entries in scene_gt_info.json')
        instances = []
        for index, (gt, info) in enumerate(zip(gts, infos)):
            where = f'image {key} instance {index}'
            obj_id = int(_field(gt, 'obj_id', scene_dir / 'scene_gt.json', where))
            instances.append(GroundTruthInstance(
                object_name=names.get(obj_id) or fallback_object_name(obj_id),
                obj_id=obj_id,
                rotation=nearest_rotation(_field(gt, 'cam_R_m2c', scene_dir / 'scene_gt.json',
                                                 where, (3, 3))),
                translation=_field(gt, 'cam_t_m2c', scene_dir / 'scene_gt.json', where,
                                   (3,)) * MM_TO_M,
                box_uv=_optional_box(info, 'bbox_obj', scene_dir, where),
                visible_box_uv=_optional_box(info, 'bbox_visib', scene_dir, where),
                visib_fract=float(_field(info, 'visib_fract',
                                         scene_dir / 'scene_gt_info.json', where))))
        return tuple(instances)
