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

"""``bbpose compare``: two ``bbpose eval`` runs, figure by figure, paired by instance."""

import argparse
from pathlib import Path

from bbpose_ros.core.eval.paired import (compare, compare_objects, format_comparison,
                                         format_objects, read_runs)
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.core.util.files import write_json_atomic


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the ``compare`` subcommand."""
    parser = subparsers.add_parser(
        'compare', help='paired difference of two eval runs, with bootstrap intervals',
        description='Pair the instances two `bbpose eval --json` runs scored (by object, '
                    'frame and ground-truth index; the records beside each report, '
                    'R.instances.json) and print each figure of A and B, the difference '
                    'B - A and its bootstrap interval: recall of found, ADD(-S), 5 cm / 5 '
                    'deg and 5 px over the paired instances, and the medians of the '
                    'translation, rotation and ADD errors over those both found.')
    parser.add_argument('a', type=_paths, help='report A (R.json or R.instances.json); '
                        'several reports of disjoint frames joined by commas make one run '
                        '(the folds of a cross-validation)')
    parser.add_argument('b', type=_paths, help='report B (likewise)')
    parser.add_argument('--objects', action='store_true',
                        help='also compare object by object (found, ADD(-S), 5 px)')
    parser.add_argument('--resamples', type=int, default=2000,
                        help='bootstrap resamples (default %(default)s)')
    parser.add_argument('--level', type=float, default=0.95,
                        help='interval level, 0..1 (default %(default)s)')
    parser.add_argument('--seed', type=int, default=0,
                        help='bootstrap seed (default %(default)s)')
    parser.add_argument('--json', type=Path, default=None,
                        help='write the figures here')
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Compare, print the table, write the JSON; returns the exit code."""
    if not 0.0 < args.level < 1.0 or args.resamples < 1:
        raise InputError('--level must be in (0, 1) and --resamples >= 1')
    a, b = read_runs(args.a), read_runs(args.b)
    figures = compare(a, b, args.resamples, args.level, args.seed)
    names = [','.join(map(str, paths)) for paths in (args.a, args.b)]
    print(format_comparison(figures, names, args.level))
    report = {'a': names[0], 'b': names[1], 'level': args.level, 'figures': figures}
    if args.objects:
        report['objects'] = compare_objects(a, b, args.resamples, args.level, args.seed)
        print('\n' + format_objects(report['objects']))
    if args.json is not None:
        write_json_atomic(args.json, report)
    return 0


def _paths(text: str) -> list[Path]:
    return [Path(part) for part in text.split(',') if part]
