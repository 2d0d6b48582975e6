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
The pseudo-labelled frames as a training set: a scene cache the students read.

The accepted labels of a recording are written as a scene cache (``training.cache``: each
frame at the detector's input size, each label's amodal box, rotation, translation and
crop), so the students draw batches exactly as they do from renders. Beside the shards,
``ignore.npz`` holds the regions of the poses the teacher saw but did not trust
(``scene`` (k,), ``object`` (k,) index into the cache's objects, ``box_uv`` (k, 4)
full-frame continuous pixels): the detector learns there neither an object nor
background.
"""

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
import json
from pathlib import Path

import numpy as np

from bbpose_ros.core.adaptation.frames import RecordedFrame
from bbpose_ros.core.adaptation.selection import Verdict
from bbpose_ros.core.training.cache import (camera_meta, CROP_CONTEXT, CROP_SIZE, scene_entry,
                                            TrainingCache, write_scene_shard)
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.core.util.files import atomic_output

IGNORE_FILE = 'ignore.npz'


@dataclass(frozen=True)
class PseudoInstance:
    """A label as ``training.cache.scene_entry`` takes an instance (visible: unknown, 1)."""

    object_name: str
    box_uv: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    visib_fract: float = 1.0


@dataclass(frozen=True)
class IgnoreRegions:
    """Boxes of untrusted poses: ``scene`` (k,), ``object_index`` (k,), ``box_uv`` (k, 4)."""

    scene: np.ndarray
    object_index: np.ndarray
    box_uv: np.ndarray

    @classmethod
    def read(cls, folder: Path | str) -> 'IgnoreRegions':
        """Read ``ignore.npz`` of a label set."""
        with np.load(Path(folder) / IGNORE_FILE) as data:
            return cls(data['scene'], data['object'], data['box_uv'])

    def of_scene(self, scene: int) -> Iterator[tuple[int, np.ndarray]]:
        """Yield (object index, box_uv (4,)) of the regions of one scene."""
        for k in np.flatnonzero(self.scene == scene):
            yield int(self.object_index[k]), self.box_uv[k]


def write_label_set(folder: Path | str, frames: Sequence[RecordedFrame],
                    verdicts: Mapping[str, Sequence[Verdict]], objects: Sequence[str],
                    input_size: Sequence[int]) -> TrainingCache:
    """
    Write the frames that hold at least one label as a scene cache, with ``ignore.npz``.

    Args:
        folder: the cache folder to write (replaced whole, atomically).
        frames: the recording's frames (one camera for all).
        verdicts: {frame key: [Verdict]} of ``selection.select_labels``.
        objects: the networks' object names (the cache's ``object`` indexes them).
        input_size: (width, height) of the detector's input.

    Returns:
        The written TrainingCache.

    Raises:
        InputError: frames of different cameras, or no accepted label at all.

    """
    cameras = {tuple(camera_meta(f.camera)) for f in frames}
    if len(cameras) > 1:
        raise InputError(f'the recording has {len(cameras)} different cameras; adapt on the '
                         'frames of one camera at a time')
    results, ignore = [], ([], [], [])
    for frame in frames:
        judged = verdicts.get(frame.key, [])
        labels = [PseudoInstance(v.pose.object_name, v.pose.box_uv, v.pose.rotation,
                                 v.pose.translation) for v in judged if v.accepted]
        if not labels:
            continue
        for verdict in judged:
            if not verdict.accepted:
                pose = verdict.pose
                ignore[0].append(len(results))
                ignore[1].append(list(objects).index(pose.object_name))
                ignore[2].append(np.concatenate([
                    np.minimum(pose.box_uv[:2], pose.detection_box_uv[:2]),
                    np.maximum(pose.box_uv[2:], pose.detection_box_uv[2:])]))
        results.append(scene_entry(frame.read(), labels, list(objects), input_size))
    if not results:
        raise InputError('the teacher accepted no label in the recording: nothing to adapt '
                         'on (see report.json for the verdicts)')
    meta = {'objects': list(objects), 'camera': list(cameras.pop()),
            'input_size': list(input_size), 'crop_size': CROP_SIZE,
            'crop_context': CROP_CONTEXT, 'shard_size': len(results),
            'source': 'bbpose adapt pseudo labels'}
    with atomic_output(folder) as staging:
        staging.mkdir()
        write_scene_shard(staging / 'shard_00000.npz', results)
        np.savez(staging / IGNORE_FILE, scene=np.array(ignore[0], dtype=int),
                 object=np.array(ignore[1], dtype=int),
                 box_uv=np.array(ignore[2], dtype=float).reshape(-1, 4))
        (staging / 'meta.json').write_text(json.dumps(meta, indent=1))
    return TrainingCache(folder)
