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

"""``bbpose train qnet``: Q-Net from a crop or scene cache."""

import argparse

from bbpose_ros.cli.train.arguments import (add_budget_options, add_common_options,
                                            add_init_option, add_qnet_options, training_run)
from bbpose_ros.cli.train.inputs import init_network, qnet_setup


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``bbpose train qnet``."""
    parser = subparsers.add_parser('qnet', help='train the qnet')
    add_common_options(parser)
    add_budget_options(parser)
    parser.set_defaults(func=run)
    add_qnet_options(parser)
    add_init_option(parser)


def run(args: argparse.Namespace) -> int:
    """Train Q-Net."""
    from bbpose_ros.core.training.runs import train_qnet
    training = training_run(args)
    cache, models, config, settings = qnet_setup(args)
    real = None
    if args.real_val:
        from bbpose_ros.core.data.bop import BopDataset
        from bbpose_ros.core.training.real_validation import RealCrops
        real = RealCrops(BopDataset(args.dataset).frames(), config.objects, models)
    train_qnet(cache, models, config, settings, training, real_crops=real,
               init=init_network(args, 'qnet', models))
    return 0
