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


"""Plain-text tables of per-object figures, as ``bbpose eval`` prints them."""

import math
from typing import Any, Mapping, Sequence

# (key in the row dict, column title, format); '{:d}' columns print as integers. The
# Markdown tables of the docs have columns of their own (report_tables.Column).
ObjectTableColumn = tuple[str, str, str]


def format_object_table(rows: Mapping[str, Mapping], mean: Mapping,
                        columns: Sequence[ObjectTableColumn], width: int) -> str:
    """
    Format one line per object and a final 'mean' line under a rule.

    ``rows`` maps object names to {key: value}; a missing, NaN or infinite value prints '-'.
    Every column is ``width`` characters wide, right-aligned; names take 12.
    """
    header = f'{"object":<12}' + ''.join(f'{title:>{width}}' for _, title, _ in columns)
    lines = [header, '-' * len(header)]
    for name, values in list(rows.items()) + [('mean', mean)]:
        cells = []
        for key, _, fmt in columns:
            value = values.get(key)
            if isinstance(value, (int, float)) and math.isfinite(value):
                text = fmt.format(int(value) if fmt == '{:d}' else value)
            else:
                text = '-'
            cells.append(f'{text:>{width}}')
        if name == 'mean':
            lines.append('-' * len(header))
        lines.append(f'{name:<12}' + ''.join(cells))
    return '\n'.join(lines)


TABLE_COLUMNS = (('n', 'n', '{:d}'), ('detected', 'found', '{:d}'),
                 ('add_s_recall', 'ADD(-S)', '{:.3f}'), ('cm5deg5', '5cm5deg', '{:.3f}'),
                 ('proj5px', 'proj5px', '{:.3f}'), ('re_median_deg', 're_med_deg', '{:.2f}'),
                 ('te_median_mm', 'te_med_mm', '{:.1f}'),
                 ('euler_mean_deg', 'euler_deg', '{:.2f}'))


def format_report(report: Mapping[str, Any]) -> str:
    """Format the per-object table of a report, with the mean row and stage timings."""
    lines = [format_object_table(report['objects'], report['mean'], TABLE_COLUMNS, 11)]
    timing = ', '.join(f'{stage} {t["median"]:.2f} ms (p95 {t["p95"]:.2f})'
                       for stage, t in report.get('timing_ms', {}).items())
    if timing:
        lines.append(f'timing per frame: {timing}')
    if report.get('sources'):
        lines.append('poses found from: ' + '; '.join(
            f'{source} {row["n"]} (ADD(-S) {row["add_s_recall"]:.3f}, 5cm5deg '
            f'{row["cm5deg5"]:.3f})' for source, row in report['sources'].items()))
    if report.get('confidence'):
        lines.append('minimum confidence: share of found poses kept, and of those kept the '
                     'share passing ADD(-S) / 5cm5deg')
        lines += [f'  >= {row["min_confidence"]:.1f}: kept {row["kept"]:.2f}, ADD(-S) '
                  f'{row["add_s_precision"]:.3f}, 5cm5deg {row["cm5deg5_precision"]:.3f}'
                  for row in report['confidence']]
    return '\n'.join(lines)
