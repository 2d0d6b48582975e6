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
Atomic outputs: a file or folder appears under its final name complete, or not at all.

Every writer of the package (reports, bags, caches, checkpoints, weights) writes through
``atomic_output``, so an interrupted or failed run never leaves a half-written output.
"""

from contextlib import contextmanager
import json
import math
import os
from pathlib import Path
import shutil
from typing import Any, Iterator

import cv2
import numpy as np


@contextmanager
def atomic_output(path: Path | str, keep_name: bool = False) -> Iterator[Path]:
    """
    Yield a temporary path to write to; rename it to ``path`` on success.

    The temporary name (``.NAME.partial-PID``, beside ``path``) is unique per process, so
    parallel workers can write different outputs of one folder. With ``keep_name`` the
    yielded path is ``.NAME.partial-PID/NAME``, for writers that name their contents after
    the output (a rosbag's data file). Write a file or create a folder at the yielded path;
    when the block raises, whatever was written is removed.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f'.{path.name}.partial-{os.getpid()}')
    _remove(tmp)
    target = tmp / path.name if keep_name else tmp
    try:
        if keep_name:
            tmp.mkdir()
        yield target
        target.replace(path)
    finally:
        _remove(tmp)


def json_safe(value: Any) -> Any:
    """Replace NaN and infinities by None, recursively, so the JSON is standard."""
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_json_atomic(path: Path | str, data: Any) -> None:
    """Write ``data`` as indented standard JSON (NaN -> null) to ``path``, atomically."""
    with atomic_output(path) as tmp:
        tmp.write_text(json.dumps(json_safe(data), indent=2) + '\n')


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def write_rgb_png(path: Path | str, image_rgb: np.ndarray) -> None:
    """
    Write an (H, W, 3) uint8 RGB image as a PNG file, whole or not at all (its folder made).

    Raises:
        OSError: the image cannot be encoded or written.

    """
    ok, data = cv2.imencode('.png', cv2.cvtColor(image_rgb, cv2.COLOR_RGB2BGR))
    if not ok:
        raise OSError(f'cannot encode image {path} ({image_rgb.shape} {image_rgb.dtype})')
    with atomic_output(path) as tmp:
        tmp.write_bytes(data.tobytes())
