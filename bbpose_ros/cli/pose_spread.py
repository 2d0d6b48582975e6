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
``bbpose pose-spread``: measure the per-object pose spread the node reports as covariance.

Runs the pipeline with the node's default settings (detector boxes, Q-Net, refinement)
over every frame of a BOP dataset (default: the LM-O development frames) and writes, per
object, the spread of its poses around the truth (``core.eval.spread``) to
``bbpose_ros/weights/pose_spread.json``, which ``ros.detections`` reads.
"""

import argparse
from datetime import date
from pathlib import Path

from tqdm import tqdm

from bbpose_ros.cli.common import add_dataset_argument
from bbpose_ros.core.data.bop import BopDataset
from bbpose_ros.core.eval.spread import pose_errors, spread_of
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.pipeline.loader import load_pipeline
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.core.util.files import write_json_atomic

OUT = Path(__file__).resolve().parents[1] / 'weights' / 'pose_spread.json'


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the ``pose-spread`` subcommand."""
    parser = subparsers.add_parser(
        'pose-spread', help="measure the node's per-object pose spread (its covariance)",
        description=__doc__.strip().splitlines()[0].split(': ', 1)[1])
    add_dataset_argument(parser)
    parser.add_argument('--json', type=Path, default=OUT,
                        help='write the spread here (default: the shipped %(default)s)')
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Measure and write the spread; returns 0."""
    dataset = BopDataset(args.dataset)
    models = dataset.load_models()
    pipeline = load_pipeline(models, PipelineOptions())
    errors = {name: [] for name in models}
    frames = dataset.frames()
    for frame in tqdm(frames, desc='measuring', unit='frame'):
        for pose in pipeline.estimate(frame.load_image(), frame.camera).poses:
            found = pose_errors(pose, frame.instances, models)
            if found is not None:
                errors[pose.object_name].append((*found, pose.confidence))
    if not any(errors.values()):
        raise InputError(f'no pose near a ground-truth instance in {args.dataset}')
    write_json_atomic(args.json, {
        'source': f'bbpose pose-spread on {len(frames)} frames of {args.dataset.name}, '
                  f'shipped weights, default settings, {date.today()}',
        'objects': {name: spread_of(rows) for name, rows in errors.items() if rows}})
    print(f'pose spread written to {args.json}')
    return 0
