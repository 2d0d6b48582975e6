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
Evaluation charts (matplotlib): recall curves, per-object recalls, errors by visibility.

Charts are written as PNG files with matplotlib's object API on the Agg canvas, so no
display and no global backend are needed; matplotlib is imported inside the chart functions
only. Overlays on frames are in ``bbpose_ros.core.pipeline.overlays``.
"""

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bbpose_ros.core.eval.instance_scores import ADD_THRESHOLD, InstanceScore
from bbpose_ros.core.eval.instance_scores import RE_THRESHOLD_DEG, TE_THRESHOLD_M

VISIBILITY_EDGES = (0.0, 0.3, 0.5, 0.7, 0.9, 1.0)


def recall_curves(scores: Mapping[str, Sequence[InstanceScore]], path: Path | str) -> None:
    """
    Write recall vs threshold of ADD(-S), rotation and translation error, one line per object.

    ``scores`` maps object names to lists of InstanceScore; a missed instance
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


def errors_by_visibility(scores: Mapping[str, Sequence[InstanceScore]], path: Path | str,
                         edges: Sequence[float] = VISIBILITY_EDGES) -> None:
    """
    Write how the errors grow as objects hide, all objects pooled, per visible-fraction bin.

    Panels: the median rotation error (deg) and translation error (mm) of the found
    instances with their interquartile range, and the shares found and within ADD(-S) of
    all instances. ``scores`` maps object names to lists of InstanceScore; bin k
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


def object_bars(per_object: Mapping[str, Mapping[str, Any]], path: Path | str,
                keys: Sequence[str] = ('add_s_recall', 'cm5deg5', 'proj5px')) -> None:
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


def refinement_basin(levels: Sequence[Mapping[str, Any]], path: Path | str) -> None:
    """
    Write 5cm5deg and ADD(-S) recall after refinement against the start's rotation error.

    ``levels`` are {'deg', 'mm', 'mean': {'cm5deg5', 'add_s_recall'}} of ``bbpose eval
    --perturb-gt`` runs, one per starting error; one line per start translation error.
    """
    figure, axes = _figure(2, width=10.0, height=4.0)
    for axis, (key, label) in zip(axes, (('cm5deg5', '5 cm / 5 deg recall'),
                                         ('add_s_recall', 'ADD(-S) recall'))):
        for mm in sorted({level['mm'] for level in levels}):
            chosen = sorted((level for level in levels if level['mm'] == mm),
                            key=lambda level: level['deg'])
            axis.plot([level['deg'] for level in chosen],
                      [level['mean'][key] for level in chosen], marker='o',
                      label=f'start moved {mm:g} mm')
        axis.set(xlabel='start rotation error (deg)', ylabel=label, ylim=(0.0, 1.0))
        axis.grid(alpha=0.3)
    axes[0].legend(fontsize='small')
    figure.suptitle('region-based refinement from perturbed ground truth')
    _save(figure, path)


def confidence_sweep(sweep: Sequence[Mapping[str, float]], path: Path | str) -> None:
    """
    Write what a minimum confidence keeps: the share of found poses, and their precision.

    ``sweep`` is ``instance_scores.confidence_sweep``'s list.
    """
    figure, (axis,) = _figure(1, width=6.0, height=4.0)
    thresholds = [row['min_confidence'] for row in sweep]
    for key, label in (('kept', 'share of found poses kept'),
                       ('add_s_precision', 'kept poses passing ADD(-S)'),
                       ('cm5deg5_precision', 'kept poses within 5 cm / 5 deg')):
        axis.plot(thresholds, [row[key] for row in sweep], marker='o', label=label)
    axis.set(xlabel='minimum confidence (refine_min_score)', ylabel='share', ylim=(0.0, 1.0))
    axis.grid(alpha=0.3)
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
