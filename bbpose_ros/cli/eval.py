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

"""``bbpose eval``: score the pipeline on a BOP dataset folder and write the report JSON."""

from pathlib import Path

from bbpose_ros.cli.common import (add_dataset_argument, add_frames_argument,
                                   add_objects_argument, write_json_atomic)
from bbpose_ros.core.bop import BopDataset
from bbpose_ros.core.evaluation import evaluate, format_report
from bbpose_ros.core.pipeline import PosePipeline


def add_parser(subparsers):
    """Register the ``eval`` subcommand."""
    parser = subparsers.add_parser(
        'eval', help='evaluate the pipeline on BOP frames (table + JSON)',
        description='Run the pipeline on the frames of a BOP dataset and score it: ADD(-S), '
                    '5 cm / 5 deg, 2D projection, rotation and translation errors per object. '
                    '--boxes gt and --rotation gt replace the learned stages by the ground '
                    'truth, to isolate the Bounding Box Equation.')
    add_dataset_argument(parser)
    parser.add_argument('--boxes', choices=('gt', 'detector'), default='detector',
                        help='2D boxes from the ground truth (amodal bbox_obj) or the detector')
    parser.add_argument('--rotation', choices=('gt', 'qnet'), default='qnet',
                        help='rotations from the ground truth or from Q-Net')
    add_objects_argument(parser)
    add_frames_argument(parser)
    parser.add_argument('--min-visib', type=float, default=0.1,
                        help='count instances at least this visible (default %(default)s)')
    parser.add_argument('--json', type=Path, default=None, help='write the report here')
    parser.set_defaults(func=run)


def build_pipeline(models, boxes, rotation):
    """Build a pipeline with learned stages only where the ground truth does not replace them."""
    if boxes == 'gt' and rotation == 'gt':
        return PosePipeline(models)
    from bbpose_ros.core.estimators import load_pipeline
    return load_pipeline(models)


def run(args):
    """Evaluate, print the table and write the JSON; returns the exit code."""
    dataset = BopDataset(args.dataset)
    models = dataset.load_models(args.objects)
    frames = dataset.frames()[:args.max_frames]
    pipeline = build_pipeline(models, args.boxes, args.rotation)
    report = evaluate(frames, pipeline, boxes=args.boxes,
                      rotation='gt' if args.rotation == 'gt' else 'estimator',
                      min_visib=args.min_visib)
    report['config'] = {'dataset': str(args.dataset), 'boxes': args.boxes,
                        'rotation': args.rotation, 'min_visib': args.min_visib}
    print(format_report(report))
    if args.json is not None:
        write_json_atomic(args.json, report)
        print(f'report written to {args.json}')
    return 0
