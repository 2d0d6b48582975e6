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
Pictures of poses: overlays drawn on frames (OpenCV) and evaluation charts (matplotlib).

Overlays draw in place on (H, W, 3) uint8 RGB images. Charts are written as PNG files with
matplotlib's object API on the Agg canvas, so no display and no global backend are needed;
matplotlib is imported by the chart functions only, which keeps it out of the node.
"""

from pathlib import Path

import cv2
import numpy as np

from bbpose_ros.core.evaluation import ADD_THRESHOLD, RE_THRESHOLD_DEG, TE_THRESHOLD_M
from bbpose_ros.core.models import BOX_EDGES

# Kelly's colours of maximum contrast, RGB 0..255, one per LineMod object id (1..15); an
# object keeps its colour in every picture and marker.
PALETTE = ((243, 195, 0), (135, 86, 146), (243, 132, 0), (161, 202, 241), (190, 0, 50),
           (194, 178, 128), (132, 132, 130), (0, 136, 86), (230, 143, 172), (0, 103, 165),
           (249, 147, 121), (96, 78, 151), (246, 166, 0), (179, 68, 108), (220, 211, 0))
GROUND_TRUTH_COLOR = (0, 255, 0)
VISIBILITY_EDGES = (0.0, 0.3, 0.5, 0.7, 0.9, 1.0)
_SUBPIXEL_BITS = 4        # cv2 drawing with 1/16 pixel precision
_MAX_COORDINATE = 1 << 20  # projected points far off the image are clipped to this


def object_color(obj_id):
    """Return the fixed (r, g, b) 0..255 colour of a BOP object id."""
    return PALETTE[(obj_id - 1) % len(PALETTE)]


def draw_box_3d(image_rgb, camera, model, rotation, translation, color, thickness=2):
    """Draw the 12 edges of the model's 3D box at pose (rotation, translation metres)."""
    corners = model.box_corners @ np.asarray(rotation).T + np.asarray(translation)
    uv = camera.project(corners)
    for start, end in BOX_EDGES:
        if corners[start, 2] > 0 and corners[end, 2] > 0:
            cv2.line(image_rgb, _point(uv[start]), _point(uv[end]), color, thickness,
                     cv2.LINE_AA, _SUBPIXEL_BITS)


def draw_box_2d(image_rgb, box_uv, color, thickness=1):
    """Draw a box [u_min, v_min, u_max, v_max] (continuous pixels)."""
    cv2.rectangle(image_rgb, _point(box_uv[:2]), _point(box_uv[2:]), color, thickness,
                  cv2.LINE_AA, _SUBPIXEL_BITS)


def draw_label(image_rgb, text, box_uv, color):
    """Write ``text`` above the box's top-left corner (inside the image)."""
    u = int(np.clip(box_uv[0], 0, image_rgb.shape[1] - 1))
    v = int(np.clip(box_uv[1] - 4, 12, image_rgb.shape[0] - 1))
    cv2.putText(image_rgb, text, (u, v), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 3,
                cv2.LINE_AA)
    cv2.putText(image_rgb, text, (u, v), cv2.FONT_HERSHEY_SIMPLEX, 0.45, color, 1,
                cv2.LINE_AA)


def draw_estimates(image_rgb, camera, models, poses):
    """
    Draw each PoseEstimate on a copy of the frame: 2D box, projected 3D box and label.

    ``models`` maps object names to ObjectModel; the label is the name and the score.
    """
    canvas = np.array(image_rgb, dtype=np.uint8, copy=True)
    for pose in poses:
        model = models[pose.object_name]
        color = object_color(model.obj_id)
        box_uv = pose.detection.box_uv
        draw_box_2d(canvas, box_uv, color)
        draw_box_3d(canvas, camera, model, pose.rotation, pose.translation, color)
        draw_label(canvas, f'{pose.object_name} {pose.detection.score:.2f}', box_uv, color)
    return canvas


def draw_comparison(image_rgb, camera, models, truths, estimates):
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


def write_image(path, image_rgb):
    """Write an RGB image as PNG."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), cv2.cvtColor(image_rgb, cv2.COLOR_RGB2BGR))


def recall_curves(scores, path):
    """
    Write recall vs threshold of ADD(-S), rotation and translation error, one line per object.

    ``scores`` maps object names to lists of evaluation.InstanceScore; a missed instance
    counts as a failure at every threshold. Dotted lines mark the report's thresholds.
    """
    panels = (
        ('ADD(-S) / diameter', np.linspace(0.0, 0.5, 101), ADD_THRESHOLD,
         lambda s: s.add_error / s.add_threshold * ADD_THRESHOLD),
        ('rotation error (deg)', np.linspace(0.0, 45.0, 91), RE_THRESHOLD_DEG,
         lambda s: s.re_deg),
        ('translation error (mm)', np.linspace(0.0, 200.0, 101), TE_THRESHOLD_M * 1e3,
         lambda s: s.te_m * 1e3),
    )
    figure, axes = _figure(len(panels), width=5.0 * len(panels), height=4.0)
    for axis, (label, thresholds, marker, error) in zip(axes, panels):
        for name, object_scores in scores.items():
            errors = np.array([error(s) for s in object_scores], dtype=float)
            with np.errstate(invalid='ignore'):
                recall = (errors[None, :] < thresholds[:, None]).mean(axis=1)
            axis.plot(thresholds, recall, label=name)
        axis.axvline(marker, color='black', linestyle=':', linewidth=1)
        axis.set(xlabel=label, ylabel='recall', ylim=(0.0, 1.0), xlim=thresholds[[0, -1]])
        axis.grid(alpha=0.3)
    axes[0].legend(fontsize='small')
    _save(figure, path)


def errors_by_visibility(scores, path, edges=VISIBILITY_EDGES):
    """
    Write how the errors grow as objects hide, all objects pooled, per visible-fraction bin.

    Panels: the median rotation error (deg) and translation error (mm) of the found
    instances with their interquartile range, and the shares found and within ADD(-S) of
    all instances. ``scores`` maps object names to lists of evaluation.InstanceScore; bin k
    holds visible fractions in (edges[k], edges[k + 1]], the first also edges[0]. Each bin's
    label gives its instance count.
    """
    pooled = [s for object_scores in scores.values() for s in object_scores]
    visib = np.array([s.visib_fract for s in pooled], dtype=float)
    bins = np.clip(np.searchsorted(edges, visib, side='left') - 1, 0, len(edges) - 2)
    labels = [(f'<= {edges[1]:.1f}' if k == 0 else f'{edges[k]:.1f}-{edges[k + 1]:.1f}')
              + f'\n(n={np.sum(bins == k)})' for k in range(len(edges) - 1)]
    positions = np.arange(len(labels))
    figure, axes = _figure(3, width=15.0, height=4.0)
    for axis, (label, error) in zip(axes, (('rotation error (deg)', lambda s: s.re_deg),
                                           ('translation error (mm)',
                                            lambda s: s.te_m * 1e3))):
        errors = np.array([error(s) for s in pooled], dtype=float)
        quartiles = np.array([np.nanpercentile(errors[bins == k], (25, 50, 75))
                              if np.isfinite(errors[bins == k]).any() else [np.nan] * 3
                              for k in positions])
        axis.fill_between(positions, quartiles[:, 0], quartiles[:, 2], alpha=0.25,
                          label='25-75 %')
        axis.plot(positions, quartiles[:, 1], marker='o', label='median')
        axis.set(ylabel=label, ylim=(0.0, None))
    found = np.array([s.detected for s in pooled], dtype=bool)
    add_ok = np.array([s.add_error < s.add_threshold for s in pooled], dtype=bool)
    for values, label in ((found, 'found'), (add_ok, 'ADD(-S) < 0.1 d')):
        axes[2].plot(positions, [values[bins == k].mean() if np.any(bins == k) else np.nan
                                 for k in positions], marker='o', label=label)
    axes[2].set(ylabel='share of instances', ylim=(0.0, 1.05))
    for axis in axes:
        axis.set_xticks(positions, labels)
        axis.set_xlabel('visible fraction')
        axis.grid(alpha=0.3)
        axis.legend(fontsize='small')
    _save(figure, path)


def object_bars(per_object, path, keys=('add_s_recall', 'cm5deg5', 'proj5px')):
    """Write grouped bars of the report's recalls (0..1) per object."""
    names = list(per_object)
    figure, (axis,) = _figure(1, width=max(6.0, 0.9 * len(names) + 2.0), height=4.0)
    width = 0.8 / len(keys)
    positions = np.arange(len(names))
    for k, key in enumerate(keys):
        values = [np.nan_to_num(per_object[name][key]) for name in names]
        axis.bar(positions + (k - (len(keys) - 1) / 2) * width, values, width, label=key)
    axis.set_xticks(positions, names, rotation=30, ha='right')
    axis.set(ylabel='recall', ylim=(0.0, 1.0))
    axis.grid(axis='y', alpha=0.3)
    axis.legend(fontsize='small')
    _save(figure, path)


def _figure(columns, width, height):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    figure = Figure(figsize=(width, height), layout='tight')
    FigureCanvasAgg(figure)
    return figure, [figure.add_subplot(1, columns, k + 1) for k in range(columns)]


def _save(figure, path):
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=100)


def _point(uv):
    """Integer cv2 point with _SUBPIXEL_BITS fractional bits; pixel centres at integers."""
    scaled = np.clip(np.asarray(uv, dtype=float) * (1 << _SUBPIXEL_BITS),
                     -_MAX_COORDINATE, _MAX_COORDINATE)
    return tuple(int(round(c)) for c in scaled)
