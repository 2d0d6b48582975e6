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

"""``bbpose docs``: fill the docs' marked tables from the reports in docs/reports/."""

import argparse
from pathlib import Path
import shlex
import subprocess
import sys

from bbpose_ros.core.eval.doc_tables import REPORT_COMMANDS, TABLES
from bbpose_ros.core.eval.report_tables import check_docs, write_docs
from bbpose_ros.core.util.errors import InputError

# The repository (or source tree) this package sits in.
ROOT = Path(__file__).resolve().parents[2]


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the ``docs`` subcommand."""
    parser = subparsers.add_parser(
        'docs', help='fill the marked tables of the docs from the reports in docs/reports/',
        description='Rewrite each table marked <!-- table: NAME --> ... <!-- /table --> in '
                    'README.md, docs/results.md and docs/performance.md from the reports of '
                    '`bbpose eval --json` and `bbpose bench --json` in docs/reports/ '
                    '(bbpose_ros/core/eval/doc_tables.py says which table shows what). With '
                    '--check, write nothing and exit 1 naming each table that differs. With '
                    '--run, first remake reports by their commands (minutes each; on a '
                    'quiet machine for the bench ones).')
    parser.add_argument('--check', action='store_true',
                        help='only compare; exit 1 if a table differs from its reports')
    parser.add_argument('--run', nargs='*', metavar='REPORT', default=None,
                        help='remake these reports (none named: all) by the command of each '
                             f'({", ".join(REPORT_COMMANDS)}), then fill the tables')
    parser.add_argument('--root', type=Path, default=ROOT,
                        help='repository folder holding README.md, docs/ and docs/reports/ '
                             '(default %(default)s)')
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Check or write the docs' tables; returns 0, or 1 when a check or a marker fails."""
    if args.run is not None:
        run_reports(args.root, args.run or list(REPORT_COMMANDS))
    if args.check:
        problems = check_docs(args.root, TABLES)
        for problem in problems:
            print(f'bbpose docs: {problem}', file=sys.stderr)
        if not problems:
            print(f'bbpose docs: {len(TABLES)} tables match their reports')
        return 1 if problems else 0
    written, problems = write_docs(args.root, TABLES)
    for problem in problems:
        print(f'bbpose docs: {problem}', file=sys.stderr)
    print(f'bbpose docs: rewrote {", ".join(written)}' if written
          else 'bbpose docs: every table was up to date')
    return 1 if problems else 0


def run_reports(root: Path, names: list[str]) -> None:
    """
    Remake reports ``names`` by their commands, each with ``--json docs/reports/NAME.json``.

    Raises InputError for an unknown name or a command that fails (its report untouched:
    the tools write atomically).
    """
    unknown = [name for name in names if name not in REPORT_COMMANDS]
    if unknown:
        raise InputError(f'unknown report(s) {", ".join(unknown)}; known: '
                         f'{", ".join(REPORT_COMMANDS)}')
    for name in names:
        words = shlex.split(REPORT_COMMANDS[name])
        command = [sys.executable, '-m', 'bbpose_ros.cli.main', *words[1:], '--json',
                   str(Path('docs') / 'reports' / f'{name}.json')]
        print(f'bbpose docs: {name}: {REPORT_COMMANDS[name]}', flush=True)
        if subprocess.run(command, cwd=root).returncode != 0:
            raise InputError(f'report {name}: {REPORT_COMMANDS[name]} failed')
