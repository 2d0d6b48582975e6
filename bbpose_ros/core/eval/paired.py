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
Paired comparison of two evaluations over the instances both saw.

``bbpose eval --json R.json`` (and ``replay-eval``) write one record per counted instance
beside the report (``write_instances``: R.instances.json, ``InstanceScore.record``). Two
runs over the same frames pair by the instance's key, so a setting's effect is measured
per instance: each figure's difference B - A with a bootstrap interval over the paired
instances, much tighter than the two runs' own sampling spread.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
import json
import math
from pathlib import Path
from typing import Any, TYPE_CHECKING

import numpy as np

from bbpose_ros.core.util.errors import InputError
from bbpose_ros.core.util.files import write_json_atomic

if TYPE_CHECKING:       # the scoring (and the pipeline it imports) only for the type
    from bbpose_ros.core.eval.instance_scores import InstanceScore

# Rates over all paired instances (a missed instance fails each).
RATES = ('found', 'add_s', 'cm5deg5', 'proj5px')
# Medians over the instances both runs found.
MEDIANS = ('te_mm', 're_deg', 'add_mm')


def instances_path(report: Path | str) -> Path:
    """Return where the instance records of report R.json lie: R.instances.json."""
    report = Path(report)
    return report.with_name(f'{report.stem}.instances.json')


def write_instances(report: Path | str,
                    scores: Mapping[str, Sequence[InstanceScore]]) -> Path:
    """Write the instance records of report R.json (``InstanceScore.record``); their path."""
    path = instances_path(report)
    write_json_atomic(path, [score.record() for object_scores in scores.values()
                             for score in object_scores])
    return path


def read_instances(path: Path | str) -> dict[str, dict[str, Any]]:
    """
    Read the instance records of a report (its path or its records' path), by key.

    Raises InputError naming the file when it is missing, not JSON, or not records.
    """
    path = Path(path)
    if not path.name.endswith('.instances.json'):
        path = instances_path(path)
    try:
        records = json.loads(path.read_text())
    except FileNotFoundError as err:
        raise InputError(f'no instance records at {path} (written by bbpose eval --json '
                         f'with this version)') from err
    except json.JSONDecodeError as err:
        raise InputError(f'{path} is not JSON: {err}') from err
    if not isinstance(records, list) or not all(isinstance(r, dict) and 'key' in r
                                                for r in records):
        raise InputError(f'{path} is not a list of instance records with a "key"')
    return {f'{r["object"]}@{r["key"]}': r for r in records}


def read_runs(paths: Sequence[Path | str]) -> dict[str, dict[str, Any]]:
    """
    Read the instance records of several reports of disjoint frames as one run.

    The folds of a cross-validation (e.g. ``bbpose adapt`` on some blocks of frames, scored
    on the others) each score their own frames; together they cover them all. Raises
    InputError when two reports score the same instance.
    """
    merged = {}
    for path in paths:
        records = read_instances(path)
        shared = sorted(set(records) & set(merged))
        if shared:
            raise InputError(f'{path} scores instances another report scores too (first: '
                             f'{shared[0]}); give reports of disjoint frames')
        merged.update(records)
    return merged


def compare_objects(a: Mapping[str, Mapping[str, Any]], b: Mapping[str, Mapping[str, Any]],
                    resamples: int = 2000, level: float = 0.95,
                    seed: int = 0) -> dict[str, dict[str, dict[str, float]]]:
    """{object: ``compare`` over that object's instances}, objects in name order."""
    names = sorted({r['object'] for r in a.values()} & {r['object'] for r in b.values()})
    return {name: compare({k: r for k, r in a.items() if r['object'] == name},
                          {k: r for k, r in b.items() if r['object'] == name},
                          resamples, level, seed) for name in names}


def format_objects(figures: Mapping[str, Mapping[str, Mapping[str, float]]],
                   names: Sequence[str] = ('found', 'add_s', 'proj5px')) -> str:
    """Make a per-object table: each figure's B - A and its interval."""
    header = f'{"object":<13}{"n":>5}' + ''.join(f'{name + " B - A":>26}' for name in names)
    lines = [header, '-' * len(header)]
    for obj, rows in figures.items():
        cells = ''.join(f'{rows[n]["diff"]:>+8.3f} [{rows[n]["low"]:+.3f}, '
                        f'{rows[n]["high"]:+.3f}]' for n in names)
        lines.append(f'{obj:<13}{rows[names[0]]["n"]:>5d}{cells}')
    return '\n'.join(lines)


def compare(a: Mapping[str, Mapping[str, Any]], b: Mapping[str, Mapping[str, Any]],
            resamples: int = 2000, level: float = 0.95, seed: int = 0
            ) -> dict[str, dict[str, float]]:
    """
    Compare runs A and B (``read_instances``) over the instances both saw.

    Returns:
        {figure: {'n': instances, 'a', 'b': the figure of each run, 'diff': b - a, 'low',
        'high': the ``level`` bootstrap interval of the difference}} for RATES (over the
        paired instances) and MEDIANS (over those both runs found; NaN without any).

    Raises:
        InputError: the runs share no instance.

    """
    keys = sorted(set(a) & set(b))
    if not keys:
        raise InputError('the two runs share no instance: were they run on the same frames '
                         'and objects?')
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, len(keys), size=(resamples, len(keys)))
    figures = {}
    for name in RATES:
        x = np.array([bool(a[k][name]) for k in keys], dtype=float)
        y = np.array([bool(b[k][name]) for k in keys], dtype=float)
        diffs = (y - x)[draws].mean(axis=1)
        figures[name] = _figure(len(keys), x.mean(), y.mean(), diffs, level)
    both = [k for k in keys if a[k]['found'] and b[k]['found']]
    for name in MEDIANS:
        x = np.array([_number(a[k][name]) for k in both])
        y = np.array([_number(b[k][name]) for k in both])
        if not len(both):
            figures[name] = _figure(0, math.nan, math.nan, np.full(1, math.nan), level)
            continue
        picks = rng.integers(0, len(both), size=(resamples, len(both)))
        diffs = np.median(y[picks], axis=1) - np.median(x[picks], axis=1)
        figures[name] = _figure(len(both), np.median(x), np.median(y), diffs, level)
    return figures


def format_comparison(figures: Mapping[str, Mapping[str, float]], names: Sequence[str],
                      level: float = 0.95) -> str:
    """Make the table of ``compare``: one line a figure, A, B, B - A and its interval."""
    header = (f'{"figure":<10}{"n":>6}{"A":>10}{"B":>10}{"B - A":>10}'
              f'   {round(level * 100)} % interval')
    lines = [f'A: {names[0]}', f'B: {names[1]}', header, '-' * len(header)]
    for name, f in figures.items():
        lines.append(f'{name:<10}{f["n"]:>6d}{f["a"]:>10.3f}{f["b"]:>10.3f}{f["diff"]:>+10.3f}'
                     f'   [{f["low"]:+.3f}, {f["high"]:+.3f}]')
    return '\n'.join(lines)


def _figure(n, a, b, diffs, level):
    tail = (1.0 - level) / 2.0
    low, high = np.quantile(diffs, [tail, 1.0 - tail])
    return {'n': int(n), 'a': float(a), 'b': float(b), 'diff': float(b - a),
            'low': float(low), 'high': float(high)}


def _number(value):
    return math.nan if value is None else float(value)
