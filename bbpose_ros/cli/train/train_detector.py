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

"""``bbpose train detector``: the box detector from a scene cache."""

import argparse

from bbpose_ros.cli.settings_options import (add_settings_options, int_tuple,
                                             settings_made, TRAINING_TITLE)
from bbpose_ros.cli.train.arguments import (add_backbone_option, add_budget_options,
                                            add_common_options, add_extra_cache_option,
                                            add_init_option, training_run)
from bbpose_ros.cli.train.inputs import init_network, load_cache
from bbpose_ros.core.training.settings import DetectorTrainSettings
from bbpose_ros.core.util.errors import InputError


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``bbpose train detector``."""
    parser = subparsers.add_parser('detector', help='train the detector')
    add_common_options(parser)
    add_budget_options(parser)
    parser.set_defaults(func=run)
    add_extra_cache_option(parser, 'scene')
    add_backbone_option(parser)
    add_init_option(parser)
    parser.add_argument('--export-input-size', type=int_tuple, default=None, metavar='W,H',
                        help='input size recorded in the --export copy, multiples of 16: the '
                             'detector is fully convolutional and may run at another size '
                             "than the cache's (default: the cache's)")
    add_settings_options(parser, DetectorTrainSettings, TRAINING_TITLE, show_defaults=True)


def run(args: argparse.Namespace) -> int:
    """Train the detector."""
    from bbpose_ros.core.nets.detector import DetectorConfig
    from bbpose_ros.core.training.runs import train_detector
    training = training_run(args)
    cache, models = load_cache(args)
    config = DetectorConfig(tuple(models), input_size=tuple(cache.input_size),
                            backbone=args.backbone)
    window = args.train_crop
    if window is None:      # the default window, cut to a smaller cache's frames
        window = tuple(min(side, full) for side, full
                       in zip(DetectorTrainSettings().train_crop, cache.input_size))
    if len(window) != 2 or any(side <= 0 or side % 16 or side > full
                               for side, full in zip(window, cache.input_size)):
        raise InputError(f'--train-crop must be W,H in multiples of 16 within the cache input '
                         f'size {tuple(cache.input_size)}, got {tuple(window)}')
    export_size = args.export_input_size
    if export_size is not None and (args.export is None or any(
            side <= 0 or side % 16 for side in export_size)):
        raise InputError('--export-input-size needs --export and W,H in multiples of 16, got '
                         f'{export_size}')
    settings = settings_made(DetectorTrainSettings, args, train_crop=tuple(window))
    train_detector(cache, config, settings, training,
                   export_input_size=None if export_size is None else tuple(export_size),
                   init=init_network(args, 'detector', models))
    return 0
