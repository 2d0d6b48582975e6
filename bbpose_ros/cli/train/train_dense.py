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

"""``bbpose train dense``: the dense correspondence net from crop caches with dense targets."""

import argparse

from bbpose_ros.cli.settings_options import add_settings_options, settings_made, TRAINING_TITLE
from bbpose_ros.cli.train.arguments import (add_budget_options, add_common_options,
                                            add_extra_cache_option, add_init_option,
                                            training_run)
from bbpose_ros.cli.train.inputs import init_network
from bbpose_ros.core.training.settings import DenseTrainSettings
from bbpose_ros.core.util.errors import InputError


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``bbpose train dense``."""
    dense = subparsers.add_parser('dense', help='train the dense correspondence net',
                                  description='Train the dense net (model coordinates, visible '
                                              'and amodal masks per cell of a crop) on crop '
                                              'caches rendered with "render-crops '
                                              '--dense-size".')
    add_common_options(dense)
    add_budget_options(dense, steps=8000)
    dense.add_argument('--crop-size', type=int, default=64,
                       help='input crop side, a multiple of 16; the maps are half of it '
                            '(default %(default)s)')
    dense.add_argument('--channels', type=int, default=64,
                       help="the decoder's width at stride 4 (default %(default)s)")
    add_extra_cache_option(dense, 'crop')
    add_init_option(dense)
    dense.add_argument('--real-val', action='store_true',
                       help="also score the real frames of --dataset's test split at every "
                            'checkpoint (ground-truth boxes, PnP poses, mask IoU); they are '
                            'never trained on')
    add_settings_options(dense, DenseTrainSettings, TRAINING_TITLE, show_defaults=True)
    dense.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Train the dense correspondence net."""
    from bbpose_ros.core.data.models import load_bop_models
    from bbpose_ros.core.nets.dense import DenseConfig
    from bbpose_ros.core.training.crop_cache import CropCache
    from bbpose_ros.core.training.runs import train_dense
    training = training_run(args)
    settings = settings_made(DenseTrainSettings, args)
    cache = CropCache([args.cache, *args.extra_cache], args.max_shards)
    models = load_bop_models(args.dataset, args.objects or cache.objects)
    try:
        config = DenseConfig(tuple(models), crop_size=args.crop_size, context=cache.context,
                             channels=args.channels)
    except ValueError as err:
        raise InputError(f'invalid dense net options: {err}') from None
    real = None
    if args.real_val:
        from bbpose_ros.core.data.bop import BopDataset
        from bbpose_ros.core.training.real_validation import RealDenseCrops
        real = RealDenseCrops(BopDataset(args.dataset).frames(), config,
                              load_bop_models(args.dataset))
    train_dense(cache, models, config, settings, training, real_crops=real,
                init=init_network(args, 'dense', models))
    return 0
