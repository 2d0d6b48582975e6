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

"""``bbpose train fig3``: the paper's Fig. 3, Q-Net with and without q-normalization."""

import argparse
import json

from bbpose_ros.cli.train.arguments import (add_budget_options, add_common_options,
                                            add_qnet_options)
from bbpose_ros.cli.train.inputs import qnet_setup
from bbpose_ros.core.training.device import training_device


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``bbpose train fig3``."""
    fig3 = subparsers.add_parser('fig3',
                                 help="the paper's Fig. 3: with vs without q-normalization")
    add_common_options(fig3)
    add_budget_options(fig3, steps=3000)
    add_qnet_options(fig3)
    fig3.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Train Q-Net with and without q-normalization and plot both losses."""
    from bbpose_ros.core.training.fig3 import q_normalization_experiment
    device = training_device(args.device)
    cache, models, config, settings = qnet_setup(args)
    summary = q_normalization_experiment(cache, models, config, settings, args.run_dir,
                                         args.steps, args.seed, args.threads, device=device)
    print(json.dumps(summary, indent=1))
    return 0
