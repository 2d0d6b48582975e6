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
A training set of scenes on disk: frames turned into detector inputs and crops.

Rendering on the CPU is far slower than training, so scenes are rendered
once, in shards of ``SHARD_SIZE``, and reused for many epochs with online augmentation.
Annotated BOP images fill the same format (``bop_import``). A shard ``shard_NNNNN.npz``
holds, for its scenes:

* ``images`` (n, H_in, W_in, 3) uint8: the frame resized to the detector input size;
* per instance (m of them, visible fraction >= MIN_VISIB): ``scene`` (m,) index into
  ``images``, ``object`` (m,) index into the cache's object list, ``box_uv`` (m, 4) amodal box
  in full-frame continuous pixels, ``visib`` (m,), ``rotation`` (m, 3, 3) egocentric
  model-to-camera, ``translation`` (m, 3) metres, ``crop`` (m, CROP_SIZE, CROP_SIZE, 3) uint8
  of ``square`` (m, 4): a square of CROP_CONTEXT times the box's longest side around it.

``meta.json`` records the objects, camera, seed and sizes. Shards are written atomically,
so an interrupted build resumes where it stopped.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
import json
import multiprocessing
from pathlib import Path
from typing import Any, Protocol, TYPE_CHECKING

import cv2
import numpy as np
from tqdm import tqdm

from bbpose_ros.core.geometry.boxes import jitter_boxes
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.nets.crops import extract_crops, square_boxes
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.core.util.files import atomic_output

if TYPE_CHECKING:
    from bbpose_ros.core.synth.crop_scenes import CropScenes
    from bbpose_ros.core.synth.scenes import SyntheticScenes
    from bbpose_ros.core.synth.table_crops import TableCrops
    from bbpose_ros.core.synth.table_scenes import TableScenes

SHARD_SIZE = 250
CROP_SIZE = 128
CROP_CONTEXT = 2.0
MIN_VISIB = 0.05

_WORKER = {}


def _init_worker(scenes, input_size):
    _WORKER['scenes'] = scenes
    _WORKER['input_size'] = input_size


class Instance(Protocol):
    """The ground truth of an object in a frame, as a synthetic or a BOP instance holds it."""

    object_name: str
    rotation: np.ndarray
    translation: np.ndarray
    box_uv: np.ndarray
    visib_fract: float


def scene_entry(image_rgb: np.ndarray, instances: Iterable[Instance],
                objects: Sequence[str],
                input_size: Sequence[int]) -> tuple[np.ndarray, dict[str, np.ndarray] | None]:
    """
    Make one scene of a shard: the frame at the detector input size, its instance records.

    Args:
        image_rgb: (H, W, 3) uint8 full frame of the cache's camera.
        instances: its ground truth (box_uv in the frame's continuous pixels), all of objects
            in ``objects``; those under MIN_VISIB visible are left out.
        objects: the cache's object names (``object`` indexes them).
        input_size: (width, height) of the stored detector image.

    Returns:
        ((H_in, W_in, 3) uint8 image, dict of instance arrays as in the module docstring, or
        None when no instance is kept).

    """
    small = cv2.resize(image_rgb, tuple(input_size), interpolation=cv2.INTER_AREA)
    kept = [i for i in instances if i.visib_fract >= MIN_VISIB]
    if not kept:
        return small, None
    boxes = np.stack([i.box_uv for i in kept])
    squares = square_boxes(boxes, CROP_CONTEXT)
    records = {
        'object': np.array([objects.index(i.object_name) for i in kept]),
        'box_uv': boxes, 'visib': np.array([i.visib_fract for i in kept]),
        'rotation': np.stack([i.rotation for i in kept]),
        'translation': np.stack([i.translation for i in kept]),
        'crop': extract_crops(image_rgb, squares, CROP_SIZE), 'square': squares,
    }
    return small, records


def _render(index):
    """Render scene ``index`` in a worker; returns ``scene_entry``'s (image, records)."""
    scenes = _WORKER['scenes']
    sample = scenes.sample(index)
    return scene_entry(sample.image_rgb, sample.instances, scenes.target_names,
                       _WORKER['input_size'])


def build_cache(scenes: SyntheticScenes | TableScenes, cache_dir: Path | str, count: int,
                input_size: Sequence[int], workers: int = 2, progress: bool = True,
                shard_size: int | None = None) -> None:
    """
    Render ``count`` scenes of a SyntheticScenes into ``cache_dir`` (resumable).

    Args:
        scenes: SyntheticScenes or TableScenes (targets = the cache's objects); a table
            cache's meta.json says ``"scene_style": "table"``.
        cache_dir: output folder (created).
        count: number of scenes; rounded up to whole shards.
        input_size: (width, height) of the stored detector images.
        workers: rendering processes (each makes its own GL context).
        progress: show a tqdm bar.
        shard_size: scenes per shard file (default ``SHARD_SIZE``).

    """
    from bbpose_ros.core.synth.table_scenes import TableScenes
    shard_size = SHARD_SIZE if shard_size is None else shard_size
    cache_dir = Path(cache_dir)
    cache_dir.mkdir(parents=True, exist_ok=True)
    meta = {'objects': scenes.target_names, 'seed': scenes.seed,
            'camera': camera_meta(scenes.camera), 'input_size': list(input_size),
            'crop_size': CROP_SIZE,
            'crop_context': CROP_CONTEXT, 'shard_size': shard_size,
            'background_photos': photo_count(scenes),
            'inplane_range_deg': list(scenes.config.inplane_range_deg)}
    if isinstance(scenes, TableScenes):     # caches of the other style keep their meta
        meta['scene_style'] = 'table'
    render_shards(cache_dir, meta, whole_shards(count, shard_size), shard_size, _init_worker,
                  (scenes, tuple(input_size)), _render, write_scene_shard, 'scene', workers,
                  progress)


def whole_shards(count: int, shard_size: int, unit: str = 'scene') -> int:
    """
    Round ``count`` up to whole shards: a render cache grows, and resumes, by shards.

    When it rounds, it says so on stdout (``unit``: what is counted, e.g. 'scene').
    """
    rounded = -(-count // shard_size) * shard_size
    if rounded != count:
        print(f'rendering {rounded} {unit}s, not {count}: whole shards of {shard_size}')
    return rounded


def render_shards(cache_dir: Path, meta: Mapping[str, Any], count: int, shard_size: int,
                  init_worker: Callable[..., None], init_args: tuple[Any, ...],
                  render: Callable[[Any], Any], write_shard: Callable[[Path, list[Any]], None],
                  unit: str, workers: int, progress: bool,
                  items: Sequence[Any] | None = None, desc: str = 'rendering') -> None:
    """
    Make ``count`` items into shard files of ``cache_dir`` in worker processes (resumable).

    ``meta`` is written to ``meta.json`` (an existing, different one is an error); each
    worker runs ``init_worker(*init_args)``, then ``render(index)`` per item index, or
    ``render(items[index])`` when ``items`` is given; the results of a shard (``shard_size``
    items, the last one possibly fewer) are written by ``write_shard(path, results)``
    (atomically). Shards already on disk are skipped, so an interrupted build resumes.
    """
    meta_path = cache_dir / 'meta.json'
    if meta_path.is_file() and json.loads(meta_path.read_text()) != meta:
        raise InputError(f'cache {cache_dir} was built with other settings ({meta_path})')
    meta_path.write_text(json.dumps(meta, indent=1))
    shards = -(-count // shard_size)
    todo = [s for s in range(shards) if not _shard_path(cache_dir, s).is_file()]
    # Spawned, not forked: EGL does not survive a fork of a process that has rendered.
    # Each worker makes its own GL context lazily.
    context = multiprocessing.get_context('spawn')
    with context.Pool(workers, init_worker, init_args) as pool, \
            tqdm(total=sum(min(shard_size, count - s * shard_size) for s in todo), desc=desc,
                 unit=unit, disable=not progress) as bar:
        for shard in todo:
            indices = range(shard * shard_size, min((shard + 1) * shard_size, count))
            tasks = indices if items is None else [items[i] for i in indices]
            results = []
            for result in pool.imap(render, tasks, chunksize=4):
                results.append(result)
                bar.update()
            write_shard(_shard_path(cache_dir, shard), results)


def camera_meta(camera: CameraIntrinsics) -> list[float]:
    """Return the ``camera`` field of a cache's meta.json: [fx, fy, cx, cy, width, height]."""
    return [camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height]


def photo_count(scenes: SyntheticScenes | TableScenes | CropScenes | TableCrops) -> int:
    """Count the background photographs of a scene source (0: procedural only)."""
    return 0 if scenes.backgrounds is None else len(scenes.backgrounds.paths)


def _shard_path(cache_dir, shard):
    return Path(cache_dir) / f'shard_{shard:05d}.npz'


def write_scene_shard(path: Path, results: Sequence[tuple[np.ndarray, Any]]) -> None:
    """
    Write the ``scene_entry`` results of one shard's scenes to ``path`` (atomically).

    A shard whose scenes have no instance at all (imported images can) gets empty instance
    arrays of the usual shapes and types.
    """
    images = np.stack([small for small, _ in results])
    arrays = {'images': images}
    records = [(k, r) for k, (_, r) in enumerate(results) if r is not None] or \
        [(0, _no_instances())]
    for key in ('object', 'box_uv', 'visib', 'rotation', 'translation', 'crop', 'square'):
        arrays[key] = np.concatenate([r[key] for _, r in records])
    arrays['scene'] = np.concatenate([np.full(len(r['object']), k) for k, r in records])
    for key in ('box_uv', 'visib', 'rotation', 'translation', 'square'):
        arrays[key] = arrays[key].astype(np.float32)
    with atomic_output(path) as tmp, open(tmp, 'wb') as stream:
        np.savez(stream, **arrays)


def _no_instances():
    """Instance records of a scene without instances (see ``scene_entry``)."""
    return {'object': np.zeros(0, dtype=int), 'box_uv': np.zeros((0, 4)), 'visib': np.zeros(0),
            'rotation': np.zeros((0, 3, 3)), 'translation': np.zeros((0, 3)),
            'crop': np.zeros((0, CROP_SIZE, CROP_SIZE, 3), dtype=np.uint8),
            'square': np.zeros((0, 4))}


class TrainingCache:
    """
    All shards of one or more cache folders, loaded into memory and concatenated.

    Attributes:
        objects: object names (index = ``object`` values).
        camera: CameraIntrinsics of the full frames.
        input_size: (width, height) of ``images``.
        images: (S, H_in, W_in, 3) uint8.
        Instance arrays as in the module docstring, with ``scene`` indexing ``images``.

    Args:
        cache_dirs: a folder, or a list of folders rendered with the same objects, camera and
            sizes (their scenes follow each other in that order).
        max_shards: use only the first N shards of each folder.

    """

    def __init__(self, cache_dirs: Path | str | Sequence[Path | str],
                 max_shards: int | None = None) -> None:
        if isinstance(cache_dirs, (str, Path)):
            cache_dirs = [cache_dirs]
        paths, first = [], None
        for cache_dir in map(Path, cache_dirs):
            meta_path = cache_dir / 'meta.json'
            if not meta_path.is_file():
                raise InputError(f'no training cache in {cache_dir} (missing meta.json); '
                                 'build it with "bbpose train render"')
            meta = json.loads(meta_path.read_text())
            try:
                layout = (meta['objects'], meta['camera'], meta['input_size'],
                          meta['crop_context'])
            except KeyError as err:
                raise InputError(f'{meta_path} is not a scene training cache (field {err} is '
                                 'missing); build one with "bbpose train render"') from err
            if first is not None and layout != first:
                raise InputError(f'training cache {cache_dir}: objects, camera or sizes differ '
                                 f'from those of {cache_dirs[0]}')
            first = layout
            found = sorted(cache_dir.glob('shard_[0-9][0-9][0-9][0-9][0-9].npz'))[:max_shards]
            if not found:
                raise InputError(f'training cache {cache_dir} has no shards yet')
            paths += found
        objects, camera, input_size, crop_context = first
        self.objects = list(objects)
        self.camera = CameraIntrinsics(*camera[:4], *map(int, camera[4:]))
        self.input_size = tuple(input_size)
        self.crop_context = float(crop_context)
        parts = [dict(np.load(p)) for p in paths]
        offsets = np.cumsum([0] + [len(p['images']) for p in parts[:-1]])
        for part, offset in zip(parts, offsets):
            part['scene'] = part['scene'] + offset
        for key in parts[0]:
            setattr(self, key, np.concatenate([p[key] for p in parts]))
        self.shards = len(paths)

    def held_out(self, fraction: float) -> np.ndarray:
        """(m,) bool: instances of the last ``fraction`` of the scenes (validation)."""
        return self.scene >= int(len(self.images) * (1 - fraction))

    def input_crops(self, ids: np.ndarray, rng: np.random.Generator, box_sigma: float,
                    size: int, context: float) -> tuple[np.ndarray, np.ndarray]:
        """
        Q-Net inputs of instances ``ids``: their boxes jittered, cut as the estimator cuts.

        Returns (n, size, size, 3) uint8 crops and the (n, 4) jittered boxes (full-frame
        continuous pixels) they are centred on.
        """
        boxes = jitter_boxes(self.box_uv[ids], rng, box_sigma)
        squares = square_boxes(boxes, context)
        crops = np.stack([extract_crops(self.crop[i], self._in_stored_crop(i, square), size)[0]
                          for i, square in zip(ids, squares)])
        return crops, boxes

    def _in_stored_crop(self, index, square):
        """Map a full-frame square (4,) into the pixel coordinates of stored crop ``index``."""
        stored = self.square[index]
        scale = self.crop.shape[1] / (stored[2] - stored[0])
        origin = np.array([stored[0], stored[1]] * 2)
        return (np.asarray(square) - origin) * scale - 0.5
