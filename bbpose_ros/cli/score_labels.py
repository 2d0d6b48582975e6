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
``bbpose score-labels``: how right ``bbpose adapt``'s pseudo labels are, against ground truth.

For measuring the adaptation on annotated frames only: ``bbpose adapt`` never reads ground
truth; this reads its output folder's teacher poses and verdicts, round by round, and
scores each against the dataset's labels (``core.eval.label_precision``).
"""

import argparse
from pathlib import Path

from bbpose_ros.cli.common import add_dataset_argument
from bbpose_ros.core.util.errors import InputError


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``bbpose score-labels``."""
    parser = subparsers.add_parser(
        'score-labels', help="score bbpose adapt's pseudo labels against ground truth",
        description='Score the labels of each round of a bbpose adapt output folder against '
                    'the ground truth of the frames it adapted on: the share right (mean '
                    'projection error under 10 px) per verdict and per object, box IoU, '
                    'translation and rotation medians.')
    parser.add_argument('adapt_out', type=Path, help='the bbpose adapt output folder')
    add_dataset_argument(parser)
    parser.add_argument('--split', default='test', help='split with the ground truth '
                        '(default %(default)s)')
    parser.add_argument('--json', type=Path, default=None, help='write the figures here')
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Score every round's labels, print a table per round; returns 0."""
    from bbpose_ros.core.adaptation.adapt_stages import read_rounds
    from bbpose_ros.core.data.bop import BopDataset
    from bbpose_ros.core.eval.label_precision import label_precision
    from bbpose_ros.core.util.files import write_json_atomic

    dataset = BopDataset(args.dataset, args.split)
    frames = dataset.frames()
    rounds = read_rounds(args.adapt_out)
    if not rounds:
        raise InputError(f'{args.adapt_out}: no round of bbpose adapt found (round1/verdicts'
                         '.json)')
    keys = {f'{f.scene_id}/{f.image_id}' for f in frames}
    models = dataset.load_models()
    report = {}
    for name, verdicts in rounds.items():
        missing = sorted(set(verdicts) - keys)
        if missing:
            raise InputError(f'{args.adapt_out} adapted on frames {args.dataset} lacks '
                             f'(first: {missing[0]}); give the dataset it adapted on')
        report[name] = label_precision(verdicts, frames, models)
        print(format_precision(name, report[name]))
    if args.json is not None:
        write_json_atomic(args.json, report)
        print(f'figures written to {args.json}')
    return 0


def format_precision(name: str, figures: dict) -> str:
    """Format one round's label precision as a text table."""
    lines = [f'{name}: labels right (mean projection error < 10 px)',
             f'{"object":14s}{"labels":>8s}{"right":>8s}{"box IoU":>9s}{"te mm":>8s}'
             f'{"re deg":>8s}']
    rows = {**figures['accepted'], 'all': figures['accepted_all']}
    for obj, row in rows.items():
        lines.append(f'{obj:14s}{row["count"]:>8d}{_cell(row["right"], 8, 3)}'
                     f'{_cell(row["box_iou_median"], 9, 3)}{_cell(row["te_median_mm"], 8, 1)}'
                     f'{_cell(row["re_median_deg"], 8, 1)}')
    lines.append('refused: ' + ', '.join(f'{v} {row["count"]} ({_cell(row["right"], 0, 2)} '
                                         'right)' for v, row in figures['verdicts'].items()
                                         if v != 'accepted'))
    return '\n'.join(lines)


def _cell(value, width, decimals):
    return f'{"-":>{width}s}' if value is None else f'{value:>{width}.{decimals}f}'
