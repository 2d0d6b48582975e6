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
A rendered set of Q-Net crops on disk (``CropScenes``, ``TableCrops``), in resumable shards.

A shard ``shard_NNNNN.npz`` holds, per crop: ``crop`` (n, S, S, 3) uint8, ``object`` (n,)
index into the cache's objects, ``box_uv`` (n, 4) amodal box and ``input_box_uv`` (n, 4)
jittered box the crop is centred on (full-frame continuous pixels), ``visib`` (n,),
``rotation`` (n, 3, 3) egocentric model-to-camera, ``translation`` (n, 3) metres.
``meta.json`` records objects, camera, seed, crop size, context and box jitter. A cache of
``TableCrops`` (``meta.json`` ``scene_style`` 'table') holds per shard the crops of
``shard_size`` table scenes, one per target visible enough.

Format version 2 (``meta.json`` ``format_version`` 2, ``dense_size`` M) adds the dense
head's targets (``core.synth.dense_targets``) on an M x M grid over each crop:
``coordinates`` (n, M, M, 3) float16 model coordinates normalised by the model box,
``visible_mask`` and ``amodal_mask`` (n, M, M) uint8 cell shares times 255. A cache without
``format_version`` is version 1 (crops only) and reads as before; it has ``dense_size`` 0.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import partial
import json
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.training.cache import camera_meta, photo_count, render_shards, \
    whole_shards
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.core.util.files import atomic_output

if TYPE_CHECKING:
    from bbpose_ros.core.synth.crop_scenes import CropSample, CropScenes
    from bbpose_ros.core.synth.table_crops import TableCrops
    from bbpose_ros.core.training.cache import TrainingCache
    from bbpose_ros.core.training.settings import TrainSettings

SHARD_SIZE = 2000
# Table scenes per shard of a TableCrops cache (each gives several crops).
TABLE_SHARD_SCENES = 250
# The cache format with dense targets; caches without them keep version 1's meta.json.
DENSE_FORMAT_VERSION = 2

_WORKER = {}


def _init_worker(scenes):
    _WORKER['scenes'] = scenes


def _render(index):
    return _WORKER['scenes'].crops(index)


def _write_crops(names, path, results):
    write_crop_shard(names, path, [crop for crops in results for crop in crops])


def write_crop_shard(names: Sequence[str], path: Path,
                     samples: Sequence[CropSample]) -> None:
    """Write one shard's crops (``CropSample``-like, ``names`` = the objects) to ``path``."""
    arrays = {
        'crop': np.stack([s.image_rgb for s in samples]),
        'object': np.array([names.index(s.object_name) for s in samples]),
        'box_uv': np.stack([s.box_uv for s in samples]).astype(np.float32),
        'input_box_uv': np.stack([s.input_box_uv for s in samples]).astype(np.float32),
        'visib': np.array([s.visib_fract for s in samples], np.float32),
        'rotation': np.stack([s.rotation for s in samples]).astype(np.float32),
        'translation': np.stack([s.translation for s in samples]).astype(np.float32),
    }
    if samples[0].coordinates is not None:
        arrays['coordinates'] = np.stack([s.coordinates for s in samples]).astype(np.float16)
        for key in ('visible_mask', 'amodal_mask'):
            arrays[key] = np.round(np.stack([getattr(s, key) for s in samples]) * 255
                                   ).astype(np.uint8)
    with atomic_output(path) as tmp, open(tmp, 'wb') as stream:
        np.savez(stream, **arrays)


def build_crop_cache(scenes: CropScenes | TableCrops, cache_dir: Path | str, count: int,
                     workers: int = 2, progress: bool = True,
                     shard_size: int | None = None) -> None:
    """
    Render ``count`` samples of a crop source into ``cache_dir`` (resumable, whole shards).

    Args:
        scenes: CropScenes (a sample is one crop) or TableCrops (a sample is one table
            scene and gives a crop per visible target); its targets are the cache's objects.
        cache_dir: output folder (created).
        count: number of samples; rounded up to whole shards of ``shard_size``.
        workers: rendering processes (each makes its own GL context).
        progress: show a tqdm bar.
        shard_size: samples per shard file (default ``SHARD_SIZE`` crops or
            ``TABLE_SHARD_SCENES`` table scenes).

    """
    from bbpose_ros.core.synth.table_crops import TableCrops
    table = isinstance(scenes, TableCrops)
    if shard_size is None:
        shard_size = TABLE_SHARD_SCENES if table else SHARD_SIZE
    cache_dir = Path(cache_dir)
    cache_dir.mkdir(parents=True, exist_ok=True)
    meta = {'kind': 'qnet_crops', 'objects': scenes.target_names, 'seed': scenes.seed,
            'camera': camera_meta(scenes.camera), 'crop_size': scenes.crop_size,
            'context': scenes.context,
            'box_sigma': scenes.box_sigma, 'min_visib': scenes.min_visib,
            'shard_size': shard_size,
            'background_photos': photo_count(scenes),
            'inplane_range_deg': list(scenes.config.inplane_range_deg)}
    if table:     # caches of the other style keep their meta
        meta['scene_style'] = 'table'
    if scenes.dense_size:
        meta.update(format_version=DENSE_FORMAT_VERSION, dense_size=scenes.dense_size)
    unit = 'scene' if table else 'crop'
    render_shards(cache_dir, meta, whole_shards(count, shard_size, unit), shard_size,
                  _init_worker, (scenes,), _render, partial(_write_crops, scenes.target_names),
                  unit, workers, progress)


def _read_meta(cache_dir):
    meta_path = Path(cache_dir) / 'meta.json'
    if not meta_path.is_file():
        raise InputError(f'no crop cache in {cache_dir} (missing meta.json); build it with '
                         '"bbpose train render-crops"')
    meta = json.loads(meta_path.read_text())
    if meta.get('kind') != 'qnet_crops':
        raise InputError(f'{meta_path} is not a Q-Net crop cache (field "kind")')
    version = meta.setdefault('format_version', 1)
    if version not in (1, DENSE_FORMAT_VERSION):
        raise InputError(f'{meta_path}: field "format_version" is {version!r}, expected 1 or '
                         f'{DENSE_FORMAT_VERSION}')
    meta.setdefault('dense_size', 0)
    return meta


def is_crop_cache(cache_dir: Path | str) -> bool:
    """Tell whether ``cache_dir`` holds a crop cache (rather than a scene cache)."""
    meta_path = Path(cache_dir) / 'meta.json'
    return meta_path.is_file() and json.loads(meta_path.read_text()).get('kind') == 'qnet_crops'


class CropCache:
    """
    All shards of one or more crop cache folders, loaded into memory and concatenated.

    Folders must agree on objects, camera, crop size and context (e.g. a procedural-background
    cache and a photograph-background one). The last crops of each folder are its held-out
    share (``held_out``).

    Attributes:
        objects: object names (index = ``object`` values).
        camera: CameraIntrinsics of the full frames the crops were cut from.
        crop_size: side of the stored crops; context: crop side / longest input-box side.
        dense_size: side of the dense targets' grid (0: the cache has none).
        folder: (m,) index of the folder each crop comes from.
        Per-crop arrays as in the module docstring.

    """

    SHARED_META = ('objects', 'camera', 'crop_size', 'context', 'dense_size')

    def __init__(self, cache_dirs: Path | str | Sequence[Path | str],
                 max_shards: int | None = None) -> None:
        dirs = [Path(cache_dirs)] if isinstance(cache_dirs, (str, Path)) else \
            [Path(d) for d in cache_dirs]
        metas = [_read_meta(d) for d in dirs]
        for folder, meta in zip(dirs[1:], metas[1:]):
            for key in self.SHARED_META:
                if meta[key] != metas[0][key]:
                    raise InputError(f'crop cache {folder}: "{key}" differs from {dirs[0]}')
        meta = metas[0]
        self.objects = list(meta['objects'])
        self.camera = CameraIntrinsics(*meta['camera'][:4], *map(int, meta['camera'][4:]))
        self.crop_size = int(meta['crop_size'])
        self.context = float(meta['context'])
        self.dense_size = int(meta['dense_size'])
        parts, folders = [], []
        for k, folder in enumerate(dirs):
            paths = sorted(folder.glob('shard_[0-9][0-9][0-9][0-9][0-9].npz'))[:max_shards]
            if not paths:
                raise InputError(f'crop cache {folder} has no shards yet')
            for path in paths:
                parts.append(dict(np.load(path)))
                folders.append(np.full(len(parts[-1]['visib']), k))
        for key in parts[0]:
            setattr(self, key, np.concatenate([p[key] for p in parts]))
        self.folder = np.concatenate(folders)
        self.shards = len(parts)

    def held_out(self, fraction: float) -> np.ndarray:
        """(m,) bool: the last ``fraction`` of each folder's crops (validation)."""
        held = np.zeros(len(self.visib), dtype=bool)
        for k in np.unique(self.folder):
            ids = np.flatnonzero(self.folder == k)
            held[ids[int(len(ids) * (1 - fraction)):]] = True
        return held

    def input_crops(self, ids: np.ndarray, rng: np.random.Generator | None,
                    box_sigma: float | None, size: int,
                    context: float) -> tuple[np.ndarray, np.ndarray]:
        """
        Return stored crops ``ids`` resized to ``size`` and the (n, 4) boxes of their centres.

        The box jitter was drawn at rendering (``box_sigma`` in meta.json), so ``rng`` and
        ``box_sigma`` are unused; ``context`` must be the cache's.
        """
        if abs(context - self.context) > 1e-6:
            raise InputError(f'crop cache has context {self.context}, the network wants '
                             f'{context}; render a cache with that context')
        crops = self.crop[ids]
        if size != self.crop_size:
            crops = np.stack([cv2.resize(c, (size, size), interpolation=cv2.INTER_AREA)
                              for c in crops])
        return crops, self.input_box_uv[ids].astype(float)


def instance_split(cache: TrainingCache | CropCache, objects: Sequence[str],
                   settings: TrainSettings, keep: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Each cached instance's network index, and the instances a run trains and validates on.

    Returns (m,) the index of each instance's object in ``objects`` (-1: not there), and
    the ids of the instances of those objects at least ``settings.min_visib`` visible (and
    ``keep``, (m,) bool, where given) outside and inside the held-out
    ``settings.val_fraction`` (``held_out``).
    """
    index = np.array([objects.index(name) if name in objects else -1
                      for name in cache.objects])[cache.object]
    usable = (index >= 0) & (cache.visib >= settings.min_visib)
    if keep is not None:
        usable &= keep
    held_out = cache.held_out(settings.val_fraction)
    return index, np.flatnonzero(usable & ~held_out), np.flatnonzero(usable & held_out)
