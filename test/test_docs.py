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

"""The docs' generated tables match the reports in docs/reports/ (``bbpose docs --check``)."""

import json
from pathlib import Path
import shutil

import pytest

from bbpose_ros.cli.main import main
from bbpose_ros.core.eval.doc_tables import REPORT_COMMANDS, TABLES
from bbpose_ros.core.eval.report_tables import (
    caption, check_docs, Column, fill_markers, report_loader, RunsTable, write_docs)
from bbpose_ros.core.util.errors import InputError

REPO_ROOT = Path(__file__).resolve().parents[1]


def _copy_docs(tmp_path):
    """Copy what the generator reads (the marked docs and the reports) to tmp_path."""
    for doc in {table.doc for table in TABLES.values()}:
        (tmp_path / doc).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(REPO_ROOT / doc, tmp_path / doc)
    shutil.copytree(REPO_ROOT / 'docs' / 'reports', tmp_path / 'docs' / 'reports')
    return tmp_path


def test_committed_docs_match_their_reports(capsys):
    assert check_docs(REPO_ROOT, TABLES) == []
    assert main(['docs', '--check', '--root', str(REPO_ROOT)]) == 0


def test_every_report_a_table_reads_is_committed_with_its_command():
    for name, table in TABLES.items():
        for report in table.reports():
            assert report in REPORT_COMMANDS, (name, report)
            assert (REPO_ROOT / 'docs' / 'reports' / f'{report}.json').is_file(), report


def test_a_changed_figure_is_named_and_make_docs_puts_it_back(tmp_path, capsys):
    root = _copy_docs(tmp_path)
    report_path = root / 'docs' / 'reports' / 'eval_detector.json'
    report = json.loads(report_path.read_text())
    report['mean']['add_s_recall'] += 0.1
    report_path.write_text(json.dumps(report))
    problems = check_docs(root, TABLES)
    named = {name for name in TABLES if any(f'table {name} differs' in p for p in problems)}
    assert len(named) == len(problems)
    assert {'readme_accuracy', 'results_runs', 'results_detector'} <= named
    assert all('eval_detector' in TABLES[name].reports() for name in named)
    assert main(['docs', '--check', '--root', str(root)]) == 1
    assert 'readme_accuracy' in capsys.readouterr().err
    written, problems = write_docs(root, TABLES)
    assert problems == [] and 'README.md' in written
    assert check_docs(root, TABLES) == []
    assert f'{report["mean"]["add_s_recall"]:.3f}' in (root / 'README.md').read_text()


def test_a_figure_typed_into_a_table_is_named(tmp_path):
    root = _copy_docs(tmp_path)
    readme = root / 'README.md'
    text = readme.read_text()
    start = text.index('<!-- table: readme_speed -->')
    end = text.index('<!-- /table -->', start)
    readme.write_text(text[:start] + text[start:end].replace('|', '| 1 |', 1) + text[end:])
    problems = check_docs(root, TABLES)
    assert len(problems) == 1 and 'readme_speed' in problems[0]


def test_markers_are_filled_and_unmarked_or_unknown_tables_are_problems(tmp_path):
    text = ('a\n<!-- table: one -->\nold\n<!-- /table -->\n'
            'b\n<!-- table: two -->\n<!-- /table -->\n')
    filled, found = fill_markers(text, {'one': 'new\n'})
    assert found == ['one', 'two']
    assert '<!-- table: one -->\nnew\n<!-- /table -->' in filled
    assert '<!-- table: two -->\n<!-- /table -->' in filled
    (tmp_path / 'docs' / 'reports').mkdir(parents=True)
    (tmp_path / 'docs' / 'reports' / 'r.json').write_text('{"mean": {"x": 0.5}}')
    (tmp_path / 'doc.md').write_text(text)
    table = RunsTable('doc.md', (Column('x', ('mean.x',)),), (('run', 'r'),))
    problems = check_docs(tmp_path, {'one': table, 'three': table})
    assert any('three is not marked' in p for p in problems)
    assert any('two has no spec' in p for p in problems)
    assert any('one differs' in p for p in problems)


def test_a_table_refuses_bench_reports_of_two_cpus(tmp_path):
    reports = tmp_path / 'docs' / 'reports'
    reports.mkdir(parents=True)
    for name, cpu in (('a', 'CPU one'), ('b', 'CPU two')):
        (reports / f'{name}.json').write_text(json.dumps({'cpu': cpu, 'stages': {}}))
    table = RunsTable('doc.md', (Column('fps', ('fps',)),), (('a', 'a'), ('b', 'b')))
    with pytest.raises(InputError, match='different CPUs'):
        caption(table, report_loader(tmp_path))
    one = RunsTable('doc.md', (Column('fps', ('fps',)),), (('a', 'a'),))
    assert 'CPU one' in caption(one, report_loader(tmp_path))


def test_an_unknown_report_to_run_is_refused_before_anything_runs(tmp_path, capsys):
    root = _copy_docs(tmp_path)
    before = {p.name: p.read_bytes() for p in (root / 'docs' / 'reports').iterdir()}
    assert main(['docs', '--run', 'eval_detector', 'no_such_report', '--root', str(root)]) == 2
    assert 'unknown report(s) no_such_report' in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in (root / 'docs' / 'reports').iterdir()} == before
