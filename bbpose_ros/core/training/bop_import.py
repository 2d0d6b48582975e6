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
Annotated BOP images (PBR renders, real frames) as training data, in the render caches.

``import_scene_cache`` fills the detector's scene cache (``cache.py``) and
``import_crop_cache`` Q-Net's crop cache (``crop_cache.py``) from one split of a BOP
folder: the same shards and meta.json fields as rendered caches (the render-only fields
``seed``, ``background_photos`` and ``inplane_range_deg`` are null where they mean nothing;
``source`` names the split), so the trainers and ``--extra-cache`` take them unchanged,
alone or mixed with renders. Like the renders they are written in shards by worker
processes, and an interrupted import resumes where it stopped.

Ground truth: poses from ``scene_gt.json``, amodal boxes from ``scene_gt_info.json``'s
``bbox_obj`` (``bop_box_to_uv``) or, where it has none, projected from the mesh's convex
hull, visible fractions from its ``visib_fract``. Images are PNG or JPEG, with their
camera per image (``scene_camera.json``).

A cache has one camera (its boxes, rays and input scaling refer to it), so each image is
resampled into the cache's camera (``in_camera``): for a pinhole camera at the same pose
this is exact, the poses stay as they are and the boxes map affinely. Parts of the cache's
frame that the image does not cover are grey (``FILL_VALUE``); the visible fractions stay
the annotation's.

``BopImages`` refuses a split holding evaluation frames (``evaluation_overlap``): the
frames ``--real-val`` and ``bbpose eval`` score must never be trained on.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import replace
from functools import partial
import hashlib
import os
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from bbpose_ros.core.data.bop import BopDataset
from bbpose_ros.core.geometry.boxes import jitter_boxes
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.projection import projected_box_uv
from bbpose_ros.core.nets.crops import extract_crops, FILL_VALUE, square_boxes
from bbpose_ros.core.synth.crop_scenes import CropSample
from bbpose_ros.core.training import cache as scene_cache
from bbpose_ros.core.training import crop_cache
from bbpose_ros.core.util.errors import InputError

if TYPE_CHECKING:
    from bbpose_ros.core.data.models import ObjectModel


def in_camera(image_rgb: np.ndarray, camera: CameraIntrinsics,
              target: CameraIntrinsics) -> np.ndarray:
    """
    Resample an (H, W, 3) uint8 image of ``camera`` into ``target``'s (same pose).

    A shrinking image is first reduced by area averaging (no aliasing), the rest is
    bilinear; pixels whose rays miss the image are ``FILL_VALUE`` grey. The image is
    returned as it is when the two cameras are equal.
    """
    if camera == target:
        return image_rgb
    scale_u, scale_v = target.fx / camera.fx, target.fy / camera.fy
    if max(scale_u, scale_v) < 1.0:
        width = max(1, round(camera.width * scale_u))
        height = max(1, round(camera.height * scale_v))
        image_rgb = cv2.resize(image_rgb, (width, height), interpolation=cv2.INTER_AREA)
        camera = camera.scaled(width, height)
    return cv2.warpAffine(image_rgb, camera.pixel_map_to(target), (target.width, target.height),
                          flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                          borderValue=(FILL_VALUE,) * 3)


def box_in_camera(box_uv: np.ndarray, camera: CameraIntrinsics,
                  target: CameraIntrinsics) -> np.ndarray:
    """Map a (4,) box [u_min, v_min, u_max, v_max] of ``camera``'s image into ``target``'s."""
    affine = camera.pixel_map_to(target)
    scale = np.array([affine[0, 0], affine[1, 1]] * 2)
    return np.asarray(box_uv, dtype=float) * scale + np.tile(affine[:, 2], 2)


def evaluation_overlap(paths: Iterable[Path | str],
                       evaluation: Iterable[Path | str]) -> list[tuple[Path, Path]]:
    """
    Return the (image, evaluation frame) pairs where an image of ``paths`` is an evaluation one.

    The same file (through any path or hard link) or a byte-identical copy. Only images of
    an evaluation frame's size are read and compared, so a large split costs one ``stat``
    an image. Missing files are skipped.
    """
    by_identity, by_size = {}, {}
    for path in map(Path, evaluation):
        stat = _stat(path)
        if stat is not None:
            by_identity[(stat.st_dev, stat.st_ino)] = path
            by_size.setdefault(stat.st_size, []).append(path)
    digests = {}

    def digest(path):
        if path not in digests:
            digests[path] = hashlib.sha256(path.read_bytes()).digest()
        return digests[path]

    found = []
    for path in map(Path, paths):
        stat = _stat(path)
        if stat is None:
            continue
        match = by_identity.get((stat.st_dev, stat.st_ino))
        if match is None:
            match = next((frame for frame in by_size.get(stat.st_size, ())
                          if digest(frame) == digest(path)), None)
        if match is not None:
            found.append((path, match))
    return found


def _stat(path):
    try:
        return os.stat(path)
    except FileNotFoundError:
        return None


class BopImages:
    """
    The annotated frames of one split of a BOP folder, none of them an evaluation frame.

    Args:
        root: BOP folder with ``camera.json`` and ``<split>/<scene>/``.
        split: the split's folder name, e.g. 'train_pbr'.
        evaluation_images: image files that must not be imported (evaluation frames).

    Attributes:
        frames: the split's BopFrames, sorted by scene and image id.
        source: what meta.json records of the split (folder, split, scenes, frame count).

    Raises:
        InputError: a missing folder, file or image, a split without images, or one holding
            evaluation frames.

    """

    def __init__(self, root: Path | str, split: str,
                 evaluation_images: Iterable[Path | str]) -> None:
        dataset = BopDataset(root, split)
        self.frames = dataset.frames()
        if not self.frames:
            raise InputError(f'no annotated images in {dataset.split_dir}')
        missing = [f.image_path for f in self.frames if not f.image_path.is_file()]
        if missing:
            raise InputError(f'{len(missing)} of the images of {dataset.split_dir} are missing, '
                             f'e.g. {missing[0]}')
        overlap = evaluation_overlap([f.image_path for f in self.frames], evaluation_images)
        if overlap:
            image, frame = overlap[0]
            raise InputError(
                f'refusing to import {dataset.split_dir}: {len(overlap)} of its images are '
                f'evaluation frames (e.g. {image} is {frame}); the frames that --real-val and '
                'bbpose eval score must never be trained on')
        self.source = {'images': str(dataset.root.resolve()), 'split': split,
                       'scenes': dataset.scene_ids, 'frames': len(self.frames)}


_WORKER = {}


def _init_worker(target, objects, hulls, settings):
    _WORKER.update(target=target, objects=objects, hulls=hulls, settings=settings, image=None)


def _image(frame):
    """Return the frame's image in the cache camera; a worker keeps the last for its crops."""
    if _WORKER['image'] is None or _WORKER['image'][0] != frame.image_path:
        _WORKER['image'] = (frame.image_path,
                            in_camera(frame.load_image(), frame.camera, _WORKER['target']))
    return _WORKER['image'][1]


def _in_target(instance, frame):
    """Return the instance with its amodal box in the cache camera (projected if it has none)."""
    if np.all(np.isfinite(instance.box_uv)):
        return replace(instance,
                       box_uv=box_in_camera(instance.box_uv, frame.camera, _WORKER['target']))
    try:
        box = projected_box_uv(_WORKER['target'], _WORKER['hulls'][instance.object_name],
                               instance.rotation, instance.translation)
    except InputError as err:
        raise InputError(f'{frame.image_path}, {instance.object_name}: {err}') from None
    return replace(instance, box_uv=box)


def _kept(instances, min_visib):
    return [i for i in instances
            if i.object_name in _WORKER['objects'] and i.visib_fract >= min_visib]


def _import_scene(frame):
    """Make a frame's ``cache.scene_entry`` (image, records), in a worker."""
    instances = [_in_target(i, frame) for i in _kept(frame.instances, scene_cache.MIN_VISIB)]
    return scene_cache.scene_entry(_image(frame), instances, _WORKER['objects'],
                                   _WORKER['settings']['input_size'])


def _import_crop(item):
    """Cut an instance's CropSample around its jittered box, in a worker."""
    frame, instance, index = item
    settings = _WORKER['settings']
    instance = _in_target(instance, frame)
    rng = np.random.default_rng([settings['seed'], 3, index])
    input_box = jitter_boxes(instance.box_uv[None], rng, settings['box_sigma'])[0]
    square = square_boxes(input_box, settings['context'])[0]
    crop = extract_crops(_image(frame), square[None], settings['crop_size'])[0]
    return CropSample(crop, instance.object_name, instance.rotation, instance.translation,
                      instance.box_uv, input_box, square, instance.visib_fract)


def _nothing_to_import(objects, min_visib, images):
    return InputError(f'no instance of {", ".join(objects)} is at least {min_visib} visible in '
                      f'{images.source["images"]} split {images.source["split"]}')


def import_scene_cache(images: BopImages, cache_dir: Path | str, camera: CameraIntrinsics,
                       models: Mapping[str, ObjectModel], input_size: Sequence[int],
                       workers: int = 2, progress: bool = True) -> int:
    """
    Fill a scene cache (the detector's, ``cache.TrainingCache``) from annotated images.

    Args:
        images: the split (``BopImages``).
        cache_dir: output folder (created; an interrupted import resumes).
        camera: the cache's CameraIntrinsics (the renders', to mix the two).
        models: {name: ObjectModel}: the cache's objects (instances of others are not
            labelled), with the hulls of the boxes to project.
        input_size: (width, height) of the stored detector images.
        workers: processes reading and resampling the images.
        progress: show a tqdm bar.

    Returns:
        The number of scenes in the cache.

    """
    objects, hulls = list(models), {name: m.hull_points for name, m in models.items()}
    if not any(i.object_name in objects and i.visib_fract >= scene_cache.MIN_VISIB
               for frame in images.frames for i in frame.instances):
        raise _nothing_to_import(objects, scene_cache.MIN_VISIB, images)
    meta = {'objects': objects, 'seed': None, 'camera': scene_cache.camera_meta(camera),
            'input_size': list(input_size), 'crop_size': scene_cache.CROP_SIZE,
            'crop_context': scene_cache.CROP_CONTEXT, 'shard_size': scene_cache.SHARD_SIZE,
            'background_photos': None, 'inplane_range_deg': None, 'source': images.source}
    settings = {'input_size': tuple(input_size)}
    Path(cache_dir).mkdir(parents=True, exist_ok=True)
    scene_cache.render_shards(Path(cache_dir), meta, len(images.frames), scene_cache.SHARD_SIZE,
                              _init_worker, (camera, objects, hulls, settings), _import_scene,
                              scene_cache.write_scene_shard, 'image', workers, progress,
                              items=images.frames, desc='importing')
    return len(images.frames)


def import_crop_cache(images: BopImages, cache_dir: Path | str, camera: CameraIntrinsics,
                      models: Mapping[str, ObjectModel], crop_size: int = 64,
                      context: float = 1.2, box_sigma: float = 0.06, min_visib: float = 0.15,
                      seed: int = 0, workers: int = 2, progress: bool = True) -> int:
    """
    Fill a Q-Net crop cache (``crop_cache.CropCache``) from annotated images.

    One crop per instance of the objects of ``models`` at least ``min_visib`` visible, cut as
    ``QNetRotationEstimator`` cuts it around the instance's amodal box jittered by
    ``box_sigma`` (per-side error / box size; drawn from (``seed``, crop index), so a resumed
    import continues the same draws), of side ``context`` x the longest side, resized to
    ``crop_size``. Other arguments as in ``import_scene_cache``.

    Returns:
        The number of crops in the cache.

    """
    objects, hulls = list(models), {name: m.hull_points for name, m in models.items()}
    items = []      # (frame without its instances, instance, crop index)
    for frame in images.frames:
        bare = replace(frame, instances=())
        for instance in frame.instances:
            if instance.object_name in objects and instance.visib_fract >= min_visib:
                items.append((bare, instance, len(items)))
    if not items:
        raise _nothing_to_import(objects, min_visib, images)
    meta = {'kind': 'qnet_crops', 'objects': objects, 'seed': seed,
            'camera': scene_cache.camera_meta(camera), 'crop_size': crop_size,
            'context': context, 'box_sigma': box_sigma, 'min_visib': min_visib,
            'shard_size': crop_cache.SHARD_SIZE, 'background_photos': None,
            'inplane_range_deg': None, 'source': images.source}
    settings = {'seed': seed, 'box_sigma': box_sigma, 'context': context,
                'crop_size': crop_size}
    Path(cache_dir).mkdir(parents=True, exist_ok=True)
    scene_cache.render_shards(Path(cache_dir), meta, len(items), crop_cache.SHARD_SIZE,
                              _init_worker, (camera, objects, hulls, settings), _import_crop,
                              partial(crop_cache.write_crop_shard, objects), 'crop', workers,
                              progress, items=items, desc='importing')
    return len(items)
