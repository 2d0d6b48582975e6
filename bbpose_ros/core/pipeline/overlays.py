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
Overlays of poses on frames, drawn with OpenCV: the node's debug image and evaluation pictures.

Everything draws on (H, W, 3) uint8 RGB images, either in place or on a copy (the
``draw_estimates`` / ``draw_comparison`` entry points). Pixel coordinates follow
``CameraIntrinsics``: the centre of pixel (col, row) is at (u, v) = (col, row).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import TYPE_CHECKING

import cv2
import numpy as np
import numpy.typing as npt

from bbpose_ros.core.data.models import BOX_EDGES, ObjectModel
from bbpose_ros.core.geometry.camera import CameraIntrinsics

if TYPE_CHECKING:
    from bbpose_ros.core.pipeline.poses import PoseEstimate


# Kelly's colours of maximum contrast, RGB 0..255, one per LineMod object id (1..15); an
# object keeps its colour in every picture and marker.
PALETTE = ((243, 195, 0), (135, 86, 146), (243, 132, 0), (161, 202, 241), (190, 0, 50),
           (194, 178, 128), (132, 132, 130), (0, 136, 86), (230, 143, 172), (0, 103, 165),
           (249, 147, 121), (96, 78, 151), (246, 166, 0), (179, 68, 108), (220, 211, 0))
GROUND_TRUTH_COLOR = (0, 255, 0)
CAPTION_SCALE = 0.6       # cv2 font scale of side_by_side captions
_SUBPIXEL_BITS = 4        # cv2 drawing with 1/16 pixel precision
_MAX_COORDINATE = 1 << 20  # projected points far off the image are clipped to this


def object_color(obj_id: int) -> tuple[int, int, int]:
    """Return the fixed (r, g, b) 0..255 colour of a BOP object id."""
    return PALETTE[(obj_id - 1) % len(PALETTE)]


def draw_box_3d(image_rgb: np.ndarray, camera: CameraIntrinsics, model: ObjectModel,
                rotation: npt.ArrayLike, translation: npt.ArrayLike, color: tuple[int, int, int],
                thickness: int = 2) -> None:
    """Draw the 12 edges of the model's 3D box at pose (rotation, translation metres)."""
    corners = model.box_corners @ np.asarray(rotation).T + np.asarray(translation)
    uv = camera.project(corners)
    for start, end in BOX_EDGES:
        if corners[start, 2] > 0 and corners[end, 2] > 0:
            cv2.line(image_rgb, _point(uv[start]), _point(uv[end]), color, thickness,
                     cv2.LINE_AA, _SUBPIXEL_BITS)


def draw_box_2d(image_rgb: np.ndarray, box_uv: Sequence[float] | np.ndarray,
                color: tuple[int, int, int], thickness: int = 1) -> None:
    """Draw a box [u_min, v_min, u_max, v_max] (continuous pixels)."""
    cv2.rectangle(image_rgb, _point(box_uv[:2]), _point(box_uv[2:]), color, thickness,
                  cv2.LINE_AA, _SUBPIXEL_BITS)


def draw_label(image_rgb: np.ndarray, text: str, box_uv: Sequence[float] | np.ndarray,
               color: tuple[int, int, int]) -> None:
    """Write ``text`` above the box's top-left corner (inside the image)."""
    u = int(np.clip(box_uv[0], 0, image_rgb.shape[1] - 1))
    v = int(np.clip(box_uv[1] - 4, 12, image_rgb.shape[0] - 1))
    cv2.putText(image_rgb, text, (u, v), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 3,
                cv2.LINE_AA)
    cv2.putText(image_rgb, text, (u, v), cv2.FONT_HERSHEY_SIMPLEX, 0.45, color, 1,
                cv2.LINE_AA)


def draw_estimates(image_rgb: npt.ArrayLike, camera: CameraIntrinsics,
                   models: Mapping[str, ObjectModel],
                   poses: Iterable[PoseEstimate]) -> np.ndarray:
    """
    Draw each PoseEstimate on a copy of the frame: 2D box, projected 3D box and label.

    ``models`` maps object names to ObjectModel; the label is the name and the confidence
    (the refinement score when refined, else the detector's).
    """
    canvas = np.array(image_rgb, dtype=np.uint8, copy=True)
    for pose in poses:
        model = models[pose.object_name]
        color = object_color(model.obj_id)
        box_uv = pose.detection.box_uv
        draw_box_2d(canvas, box_uv, color)
        draw_box_3d(canvas, camera, model, pose.rotation, pose.translation, color)
        draw_label(canvas, f'{pose.object_name} {pose.confidence:.2f}', box_uv, color)
    return canvas


def draw_comparison(image_rgb: npt.ArrayLike, camera: CameraIntrinsics,
                    models: Mapping[str, ObjectModel],
                    truths: Iterable[tuple[str, np.ndarray, np.ndarray]],
                    estimates: Iterable[tuple[str, np.ndarray, np.ndarray]]) -> np.ndarray:
    """
    Draw ground-truth boxes (green, thin) and estimates (object colour) on a copy.

    ``truths`` and ``estimates`` are lists of (object name, rotation (3, 3), translation (3,)
    metres).
    """
    canvas = np.array(image_rgb, dtype=np.uint8, copy=True)
    for name, rotation, translation in truths:
        draw_box_3d(canvas, camera, models[name], rotation, translation, GROUND_TRUTH_COLOR, 1)
    for name, rotation, translation in estimates:
        model = models[name]
        draw_box_3d(canvas, camera, model, rotation, translation, object_color(model.obj_id))
        corners = camera.project(model.box_corners @ rotation.T + translation)
        draw_label(canvas, name, np.concatenate([corners.min(0), corners.max(0)]),
                   object_color(model.obj_id))
    return canvas


def tile_grid(images_rgb: Sequence[np.ndarray], columns: int,
              tile_size: tuple[int, int]) -> np.ndarray:
    """
    Lay images out in rows of ``columns``, each shrunk to ``tile_size`` (width, height).

    Args:
        images_rgb: (H, W, 3) uint8 RGB images, any sizes (at least one).
        columns: tiles per row; the last row is filled with black tiles.
        tile_size: (width, height) of a tile in pixels.

    Returns:
        (rows * height, columns * width, 3) uint8 RGB.

    """
    tiles = [cv2.resize(image, tuple(tile_size), interpolation=cv2.INTER_AREA)
             for image in images_rgb]
    tiles += [np.zeros_like(tiles[0])] * (-len(tiles) % columns)
    return np.concatenate([np.concatenate(tiles[k:k + columns], axis=1)
                           for k in range(0, len(tiles), columns)])


def _point(uv):
    """Integer cv2 point with _SUBPIXEL_BITS fractional bits; pixel centres at integers."""
    scaled = np.clip(np.asarray(uv, dtype=float) * (1 << _SUBPIXEL_BITS),
                     -_MAX_COORDINATE, _MAX_COORDINATE)
    return tuple(int(round(c)) for c in scaled)


def side_by_side(panels: Sequence[tuple[np.ndarray, str]]) -> np.ndarray:
    """
    Put (H, W, 3) uint8 RGB images of one height side by side, each captioned top left.

    ``panels``: [(image, caption)]; the captions are drawn on copies.
    """
    captioned = []
    for image, caption in panels:
        canvas = np.array(image, dtype=np.uint8, copy=True)
        (width, height), baseline = cv2.getTextSize(caption, cv2.FONT_HERSHEY_SIMPLEX,
                                                    CAPTION_SCALE, 1)
        cv2.rectangle(canvas, (0, 0), (width + 8, height + baseline + 8), (0, 0, 0), -1)
        cv2.putText(canvas, caption, (4, height + 4), cv2.FONT_HERSHEY_SIMPLEX,
                    CAPTION_SCALE, (255, 255, 255), 1, cv2.LINE_AA)
        captioned.append(canvas)
    return np.concatenate(captioned, axis=1)
