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

"""``bbpose train verifier``: the detector's second stage, on a trained detector's candidates."""

import argparse
from pathlib import Path

from bbpose_ros.cli.settings_options import (add_settings_options, int_tuple,
                                             settings_made, TRAINING_TITLE)
from bbpose_ros.cli.train.arguments import (add_budget_options, add_common_options,
                                            add_extra_cache_option, training_run)
from bbpose_ros.core.training.settings import VerifierTrainSettings
from bbpose_ros.core.util.errors import InputError

VERIFIER_CHANNELS = (12, 24, 48, 48)


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``bbpose train verifier``."""
    verifier = subparsers.add_parser('verifier', help="train the detector's second stage")
    add_common_options(verifier)
    add_budget_options(verifier, steps=8000)
    verifier.add_argument('--detector-weights', type=Path, required=True,
                          help='the trained detector whose candidates are re-scored (its '
                               'first stage is kept, a second stage in it is replaced)')
    verifier.add_argument('--channels', type=int_tuple, default=VERIFIER_CHANNELS,
                          help='widths of the four conv stages (default %(default)s)')
    verifier.add_argument('--crop-size', type=int, default=32,
                          help='crop side, a multiple of 8 (default %(default)s)')
    verifier.add_argument('--context', type=float, default=1.2,
                          help='crop side / longest box side (default %(default)s)')
    verifier.add_argument('--candidates', type=int, default=3,
                          help='peaks per class re-scored at run time (default %(default)s)')
    add_extra_cache_option(verifier, 'scene')
    verifier.add_argument('--real-val', action='store_true',
                          help="also measure the detector's recall on the dataset's real "
                               'frames (measured only, never trained on)')
    add_settings_options(verifier, VerifierTrainSettings, TRAINING_TITLE, show_defaults=True)
    verifier.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Train the detector's second stage."""
    from bbpose_ros.core.inference.weights import load_network
    from bbpose_ros.core.training.cache import TrainingCache
    from bbpose_ros.core.training.runs import train_verifier, with_verifier
    if args.candidates < 1:
        raise InputError(f'--candidates must be at least 1, got {args.candidates}')
    if args.crop_size < 8 or args.crop_size % 8:
        raise InputError(f'--crop-size must be a positive multiple of 8, got {args.crop_size}')
    if len(args.channels) != 4:
        raise InputError(f'--channels needs 4 widths, got {len(args.channels)}')
    training = training_run(args)
    settings = settings_made(VerifierTrainSettings, args)
    detector = load_network(args.detector_weights, 'detector')
    cache = TrainingCache([args.cache, *args.extra_cache], args.max_shards)
    if tuple(cache.input_size) != tuple(detector.config.input_size):
        raise InputError(f'training cache {args.cache}: input size {cache.input_size} is not '
                         f"the detector's {detector.config.input_size}")
    cascade = with_verifier(detector, args.channels, args.crop_size, args.context,
                            args.candidates)
    real = None
    if args.real_val:
        from bbpose_ros.core.data.bop import BopDataset
        from bbpose_ros.core.training.real_validation import RealDetections
        real = RealDetections(BopDataset(args.dataset).frames(), cascade.config.objects)
    train_verifier(cache, cascade, settings, training, real_frames=real)
    return 0
