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

"""Videos of (H, W, 3) uint8 RGB frames, written with OpenCV, atomically."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import cv2
import numpy as np

from bbpose_ros.core.util.errors import InputError
from bbpose_ros.core.util.files import atomic_output

# MPEG-4 Part 2, the one MP4 codec OpenCV's pip wheel writes (it has no H.264 encoder);
# VLC, mpv, ffplay and OpenCV play it, some browsers do not.
FOURCC = 'mp4v'


def write_video(path: Path | str, images_rgb: Iterable[np.ndarray], fps: float) -> int:
    """
    Write frames of one size as an .mp4 video at ``fps`` frames/s; return how many.

    The file appears complete under ``path`` or not at all. InputError when there are no
    frames, a frame's size differs from the first's, or OpenCV cannot write ``path``.
    """
    path = check_video_path(path)
    count, writer = 0, None
    # keep_name: the temporary file keeps the .mp4 suffix that tells OpenCV the container.
    with atomic_output(path, keep_name=True) as tmp:
        try:
            for image in images_rgb:
                height, width = image.shape[:2]
                if writer is None:
                    size = (width, height)
                    writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*FOURCC), fps,
                                             size)
                    if not writer.isOpened():
                        raise InputError(f'video {path}: OpenCV cannot write {FOURCC} .mp4')
                if (width, height) != size:
                    raise InputError(f'video {path}: frame {count} is {width}x{height}, '
                                     f'the first was {size[0]}x{size[1]}')
                writer.write(cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
                count += 1
        finally:
            if writer is not None:
                writer.release()
        if count == 0:
            raise InputError(f'video {path}: no frames to write')
    return count


def check_video_path(path: Path | str) -> Path:
    """Return ``path`` as a Path; InputError unless it names an .mp4 file."""
    path = Path(path)
    if path.suffix.lower() != '.mp4':
        raise InputError(f'video {path}: give a file name ending in .mp4')
    return path
