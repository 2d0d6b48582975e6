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
Markdown tables of the docs, filled from the JSON reports of ``bbpose eval`` and ``bench``.

A doc marks each generated table by name::

    <!-- table: results_detector -->
    (whatever the generator wrote last)
    <!-- /table -->

and ``core/eval/doc_tables.py`` says what each table shows: which report files (under
``docs/reports/``, named without ``.json``), which rows and which keys. ``render_docs``
rewrites the marked blocks, ``check_docs`` names the tables whose text differs from what
their reports give. Four kinds of table:

* ``RunsTable``: one row per report (a run of ``bbpose eval`` or ``bench``), the same keys
  in every row;
* ``ObjectsTable``: one row per object of one eval report, then its mean;
* ``StagesTable``: one row per stage, one column per (bench report, mode);
* ``ListTable``: one row per item of a list in one report (a ``--perturb-gt`` sweep).

Every table starts with a line naming its reports and the command that wrote them (its
``tool``); one holding bench reports also names their CPU, and refuses reports of
different CPUs.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
import json
import math
from pathlib import Path
import re
from typing import Any

from bbpose_ros.core.util.errors import InputError
from bbpose_ros.core.util.files import atomic_output

REPORTS_DIR = Path('docs', 'reports')
MARKER = re.compile(r'<!-- table: (?P<name>[\w-]+) -->\n(?P<body>.*?)<!-- /table -->',
                    re.DOTALL)

Loader = Callable[[str], Mapping[str, Any]]


@dataclass(frozen=True)
class Column:
    """
    One column: its title and the keys of its cell.

    ``keys`` are dotted paths into a report (``mean.add_s_recall``); several are joined by
    ' / ' in one cell. ``fmt`` formats each number (``'{}'`` for text); a missing key or a
    non-finite number prints '-'. ``report`` takes the cell from another report than the
    row's.
    """

    title: str
    keys: tuple[str, ...]
    fmt: str = '{:.3f}'
    report: str | None = None


@dataclass(frozen=True)
class RunsTable:
    """One row per report: ``rows`` are (label, report name)."""

    doc: str
    columns: tuple[Column, ...]
    rows: tuple[tuple[str, str], ...]
    first: str = 'run'
    tool: str = 'bbpose eval'

    def reports(self) -> list[str]:
        """Name the reports the table reads, in order."""
        return _unique([r for _, r in self.rows] + [c.report for c in self.columns if c.report])

    def render(self, load: Loader) -> list[str]:
        """Make the table's markdown lines."""
        body = [[label] + [cell(load(column.report or report), column)
                           for column in self.columns]
                for label, report in self.rows]
        return markdown_table([self.first] + [c.title for c in self.columns], body)


@dataclass(frozen=True)
class ObjectsTable:
    """
    One row per object of a report, then the row of all objects.

    In the columns' keys ``{o}`` stands for ``objects.NAME`` (``last`` in the last row) and
    ``{d}`` for ``detection.NAME`` (``detection.mean``). ``last`` is the report's key of the
    figures over all objects: an eval report's ``mean``, a comparison's pooled ``figures``.
    """

    doc: str
    report: str
    columns: tuple[Column, ...]
    last: tuple[str, str] = ('mean', '**mean**')
    tool: str = 'bbpose eval'

    def reports(self) -> list[str]:
        """Name the reports the table reads."""
        return _unique([self.report] + [c.report for c in self.columns if c.report])

    def render(self, load: Loader) -> list[str]:
        """Make the table's markdown lines."""
        report = load(self.report)
        body = []
        key, label = self.last
        for name in list(report.get('objects', {})) + [None]:
            where = {'o': key if name is None else f'objects.{name}',
                     'd': f'detection.{name or "mean"}'}
            cells = [cell(load(c.report or self.report),
                          Column(c.title, tuple(k.format(**where) for k in c.keys), c.fmt))
                     for c in self.columns]
            body.append([label if name is None else name] + cells)
        return markdown_table(['object'] + [c.title for c in self.columns], body)


@dataclass(frozen=True)
class StagesTable:
    """
    One row per stage (label, keys, format), one column per (title, report, key prefix).

    A row's keys are read under the column's prefix (``all_objects.`` for that mode).
    """

    doc: str
    rows: tuple[tuple[str, tuple[str, ...], str], ...]
    columns: tuple[tuple[str, str, str], ...]
    first: str = 'stage'
    tool: str = 'bbpose bench'

    def reports(self) -> list[str]:
        """Name the reports the table reads, in order."""
        return _unique([report for _, report, _ in self.columns])

    def render(self, load: Loader) -> list[str]:
        """Make the table's markdown lines."""
        body = [[label] + [cell(load(report),
                                Column(title, tuple(prefix + k for k in keys), fmt))
                           for title, report, prefix in self.columns]
                for label, keys, fmt in self.rows]
        return markdown_table([self.first] + [title for title, _, _ in self.columns], body)


@dataclass(frozen=True)
class ListTable:
    """
    One row per item of a list in one report (``sweep``, ``confidence``).

    ``label`` makes each row's first cell from the item, the columns the others.
    """

    doc: str
    report: str
    items: str
    label: Column
    columns: tuple[Column, ...]
    tool: str = 'bbpose eval'

    def reports(self) -> list[str]:
        """Name the report the table reads."""
        return [self.report]

    def render(self, load: Loader) -> list[str]:
        """Make the table's markdown lines."""
        items = lookup(load(self.report), self.items) or []
        body = [[cell(item, self.label)] + [cell(item, c) for c in self.columns]
                for item in items]
        return markdown_table([self.label.title] + [c.title for c in self.columns], body)


Table = RunsTable | ObjectsTable | StagesTable | ListTable


def lookup(report: Mapping[str, Any], key: str) -> Any:
    """Read a dotted key path from a report; None where any part is missing."""
    value: Any = report
    for part in key.split('.'):
        if not isinstance(value, Mapping) or part not in value:
            return None
        value = value[part]
    return value


def cell(report: Mapping[str, Any], column: Column) -> str:
    """Format a column's keys of ``report`` as one cell; a dash where all are missing."""
    texts = []
    for key in column.keys:
        value = lookup(report, key)
        if isinstance(value, bool):
            texts.append('yes' if value else 'no')
        elif value is None or isinstance(value, (dict, list)):
            texts.append('-')
        elif isinstance(value, (int, float)):
            texts.append(column.fmt.format(value) if math.isfinite(value) else '-')
        else:
            texts.append(str(value))
    return '-' if set(texts) == {'-'} else ' / '.join(texts)


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    """Make the lines of a markdown table."""
    lines = ['| ' + ' | '.join(header) + ' |', '|' + ' --- |' * len(header)]
    return lines + ['| ' + ' | '.join(row) + ' |' for row in rows]


def caption(table: Table, load: Loader) -> str:
    """
    Name a table's reports, and for bench reports their CPU and threads.

    Raises:
        InputError: the table mixes bench reports of different CPUs.

    """
    names = table.reports()
    files = ', '.join(f'{name}.json' for name in names)
    made = f'generated by `make docs` from docs/reports/ {files}'
    benches = [load(name) for name in names if 'stages' in load(name) or 'latency' in
               load(name)]
    if not benches:
        return f'*`{table.tool}`; {made}.*'
    cpus = {str(b.get('cpu', 'an unrecorded CPU')) for b in benches}
    if len(cpus) > 1:
        raise InputError(f'{", ".join(names)} come from different CPUs: {sorted(cpus)}')
    first = benches[0]
    threads = lookup(first, 'inference_threads')
    where = f'{cpus.pop()} ({first.get("cpu_count", "?")} CPUs)'
    if threads is not None:
        where += f', {threads} inference thread{"s" if threads != 1 else ""}'
    return f'*`bbpose bench` on {where}, milliseconds; {made}.*'


def render_table(table: Table, load: Loader) -> str:
    """Make a marked block's contents: the caption, a blank line and the table."""
    return '\n'.join([caption(table, load), ''] + table.render(load)) + '\n'


def report_loader(root: Path) -> Loader:
    """Load reports by name from ``root/docs/reports``, each once."""
    cache: dict[str, Mapping[str, Any]] = {}

    def load(name: str) -> Mapping[str, Any]:
        if name not in cache:
            path = root / REPORTS_DIR / f'{name}.json'
            try:
                cache[name] = json.loads(path.read_text())
            except (OSError, ValueError) as err:
                raise InputError(f'report {path}: {err}') from err
        return cache[name]
    return load


def fill_markers(text: str, blocks: Mapping[str, str]) -> tuple[str, list[str]]:
    """
    Replace the body of each marked table of ``text`` whose name is in ``blocks``.

    Returns:
        the new text and the names of the marked tables found, in order.

    """
    found = []

    def replace(match: re.Match) -> str:
        name = match.group('name')
        found.append(name)
        if name not in blocks:
            return match.group(0)
        return f'<!-- table: {name} -->\n{blocks[name]}<!-- /table -->'
    return MARKER.sub(replace, text), found


def render_docs(root: Path, tables: Mapping[str, Table]) -> tuple[dict[str, str], list[str]]:
    """
    Fill every doc's marked tables from the reports under ``root``.

    Returns:
        {doc path: its new text} for each doc named by ``tables``, and the problems:
        a table its doc does not mark, a marked name no table has, a name marked twice.

    """
    load = report_loader(root)
    texts, problems = {}, []
    for doc in _unique([t.doc for t in tables.values()]):
        path = root / doc
        try:
            text = path.read_text()
        except OSError as err:
            raise InputError(f'{path}: {err}') from err
        blocks = {name: render_table(t, load) for name, t in tables.items() if t.doc == doc}
        texts[doc], found = fill_markers(text, blocks)
        problems += [f'{doc}: table {name} is not marked' for name in blocks
                     if name not in found]
        problems += [f'{doc}: marked table {name} has no spec' for name in _unique(found)
                     if name not in blocks]
        problems += [f'{doc}: table {name} is marked twice' for name in _unique(found)
                     if found.count(name) > 1]
    return texts, problems


def check_docs(root: Path, tables: Mapping[str, Table]) -> list[str]:
    """Name each marked table that differs from what its reports give, and any problem."""
    texts, problems = render_docs(root, tables)
    for doc, text in texts.items():
        current = dict(_blocks((root / doc).read_text()))
        for name, body in _blocks(text):
            if current.get(name) != body:
                problems.append(f'{doc}: table {name} differs from its reports '
                                f'({", ".join(tables[name].reports())})')
    return problems


def write_docs(root: Path, tables: Mapping[str, Table]) -> tuple[list[str], list[str]]:
    """Rewrite the docs whose marked tables changed, atomically; returns (written, problems)."""
    texts, problems = render_docs(root, tables)
    written = []
    for doc, text in texts.items():
        path = root / doc
        if path.read_text() != text:
            with atomic_output(path) as tmp:
                tmp.write_text(text)
            written.append(doc)
    return written, problems


def _blocks(text: str) -> list[tuple[str, str]]:
    return [(m.group('name'), m.group('body')) for m in MARKER.finditer(text)]


def _unique(items: Sequence[Any]) -> list[Any]:
    return list(dict.fromkeys(items))
