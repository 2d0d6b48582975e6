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

"""Background images: photographs or procedural patterns, plus random shapes."""

from collections.abc import Collection, Iterable
from pathlib import Path
from typing import Any, Self

import cv2
import numpy as np

from bbpose_ros.core.util.errors import InputError


def _gradient(rng, height, width):
    """Paint a linear gradient between two random colours along a random direction."""
    angle = rng.uniform(0.0, 2.0 * np.pi)
    rows, cols = np.mgrid[0:height, 0:width].astype(np.float32)
    ramp = np.cos(angle) * cols / width + np.sin(angle) * rows / height
    ramp = (ramp - ramp.min()) / max(float(np.ptp(ramp)), 1e-6)
    colors = rng.uniform(0, 255, (2, 3)).astype(np.float32)
    return colors[0] + ramp[..., None] * (colors[1] - colors[0])


def _smooth_noise(rng, height, width):
    """Paint multi-scale value noise, coloured between two random colours per channel."""
    noise = np.zeros((height, width, 3), np.float32)
    for octave in range(rng.integers(1, 5)):
        cells = 2 ** (octave + rng.integers(1, 4))
        grid = rng.random((cells, max(cells * width // height, 1), 3)).astype(np.float32)
        noise += cv2.resize(grid, (width, height), interpolation=cv2.INTER_CUBIC) / 2 ** octave
    noise = (noise - noise.min()) / max(float(np.ptp(noise)), 1e-6)
    low, high = rng.uniform(0, 255, (2, 3)).astype(np.float32)
    return low + noise * (high - low)


def _stripes(rng, height, width):
    """Paint stripes or a checkerboard of two random colours, random period and orientation."""
    period = rng.uniform(8.0, 80.0)
    angle = rng.uniform(0.0, np.pi)
    rows, cols = np.mgrid[0:height, 0:width].astype(np.float32)
    along = (np.cos(angle) * cols + np.sin(angle) * rows) / period
    pattern = np.floor(along) % 2
    if rng.random() < 0.5:
        across = (-np.sin(angle) * cols + np.cos(angle) * rows) / period
        pattern = (pattern + np.floor(across)) % 2
    colors = rng.uniform(0, 255, (2, 3)).astype(np.float32)
    return colors[0] + pattern[..., None] * (colors[1] - colors[0])


def _draw_shapes(rng, image, count):
    """Draw ``count`` random filled or outlined circles, rectangles, lines and polygons."""
    height, width = image.shape[:2]
    for _ in range(count):
        color = tuple(float(c) for c in rng.uniform(0, 255, 3))
        thickness = -1 if rng.random() < 0.6 else int(rng.integers(1, 8))
        kind = rng.integers(4)
        x, y = int(rng.integers(width)), int(rng.integers(height))
        size = int(rng.integers(5, max(width, height) // 3))
        if kind == 0:
            cv2.circle(image, (x, y), size, color, thickness, cv2.LINE_AA)
        elif kind == 1:
            cv2.rectangle(image, (x, y), (x + size, y + int(rng.integers(5, size + 6))), color,
                          thickness)
        elif kind == 2:
            end = (int(rng.integers(width)), int(rng.integers(height)))
            cv2.line(image, (x, y), end, color, int(rng.integers(1, 12)), cv2.LINE_AA)
        else:
            points = rng.integers(-size, size + 1, (int(rng.integers(3, 7)), 2)) + [x, y]
            cv2.fillPoly(image, [points.astype(np.int32)], color, cv2.LINE_AA)


class PhotoBackgrounds:
    """
    Random regions of photographs, as backgrounds: real clutter that procedural ones lack.

    ``paths`` are image files (JPEG, PNG, WebP); they are read lazily, once per process, and
    shrunk to at most ``max_side`` pixels. Any folder of photographs works, e.g. Debian's
    wallpaper packages (see docs/training.md).
    """

    SUFFIXES = ('.jpg', '.jpeg', '.png', '.webp')

    def __init__(self, paths: Iterable[Path | str], max_side: int = 800) -> None:
        self.paths = sorted(str(p) for p in paths)
        if not self.paths:
            raise InputError('no background photographs given')
        self.max_side = max_side
        self._images = None

    @classmethod
    def from_folders(cls, folders: Collection[Path | str]) -> Self:
        """Collect every photograph under ``folders`` (recursively)."""
        paths = [p for folder in folders for p in Path(folder).rglob('*')
                 if p.suffix.lower() in cls.SUFFIXES]
        if not paths:
            raise InputError(f'no .jpg/.png/.webp images under {", ".join(map(str, folders))}')
        return cls(paths)

    def __getstate__(self) -> dict[str, Any]:
        """Pickle the paths only; each process reads the images itself."""
        state = self.__dict__.copy()
        state['_images'] = None
        return state

    def region(self, rng: np.random.Generator, height: int, width: int) -> np.ndarray:
        """(height, width, 3) uint8 RGB: a random region of a random photograph."""
        if self._images is None:
            self._images = [self._read(path) for path in self.paths]
        photo = self._images[rng.integers(len(self._images))]
        rows, cols = photo.shape[:2]
        scale = rng.uniform(0.15, 1.0) * min(rows / height, cols / width)
        h, w = max(int(height * scale), 8), max(int(width * scale), 8)
        h, w = min(h, rows), min(w, cols)
        top, left = rng.integers(0, rows - h + 1), rng.integers(0, cols - w + 1)
        region = photo[top:top + h, left:left + w]
        if rng.random() < 0.5:
            region = region[:, ::-1]
        return cv2.resize(np.ascontiguousarray(region), (width, height),
                          interpolation=cv2.INTER_AREA)

    def _read(self, path):
        image = cv2.imread(path, cv2.IMREAD_COLOR)
        if image is None:
            raise InputError(f'cannot read background image {path}')
        scale = self.max_side / max(image.shape[:2])
        if scale < 1:
            image = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def random_background(rng: np.random.Generator, height: int, width: int,
                      photos: PhotoBackgrounds | None = None,
                      photo_probability: float = 0.7) -> np.ndarray:
    """
    Make a random (height, width, 3) uint8 RGB background.

    With ``photos`` (a PhotoBackgrounds), a photograph's region is the base with
    ``photo_probability``, else a procedural pattern; random shapes go on top of either.
    """
    if photos is not None and rng.random() < photo_probability:
        image = photos.region(rng, height, width)
        _draw_shapes(rng, image, int(rng.integers(0, 6)))
    else:
        base = (_gradient, _smooth_noise, _stripes)[rng.integers(3)](rng, height, width)
        image = np.clip(base, 0, 255).astype(np.uint8)
        _draw_shapes(rng, image, int(rng.integers(0, 40)))
    if rng.random() < 0.5:
        image = cv2.GaussianBlur(image, (0, 0), rng.uniform(0.5, 3.0))
    # Real backgrounds are far less saturated than random colours: mix towards grey.
    gray = image.mean(axis=2, keepdims=True)
    return (gray + (image - gray) * rng.uniform(0.0, 1.0)).astype(np.uint8)
