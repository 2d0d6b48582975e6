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
The options the ``bbpose train`` stages share, and what their values turn into.

A stage's training settings (``core/training/settings.py``) become its options by the
one generator of options from declared settings (``cli/settings_options.py``:
``add_settings_options`` with ``TRAINING_TITLE``, ``settings_made``).
"""

from __future__ import annotations

import argparse
from dataclasses import fields
import os
from pathlib import Path
from typing import TYPE_CHECKING

from bbpose_ros.cli.common import (add_dataset_argument, add_objects_argument, float_pair,
                                   with_inplane_range)
from bbpose_ros.cli.settings_options import add_settings_options, int_tuple, TRAINING_TITLE
from bbpose_ros.core.nets.efficientnet_lite import BACKBONES
from bbpose_ros.core.nets.qnet import QNetConfig, ROTATION_TARGETS, SHARING_MODES
from bbpose_ros.core.synth.config import STORED_CROP_SIZE
from bbpose_ros.core.synth.table_config import TableConfig
from bbpose_ros.core.training.device import DEVICES
from bbpose_ros.core.training.settings import QNetTrainSettings
from bbpose_ros.core.util.errors import InputError

if TYPE_CHECKING:
    from bbpose_ros.core.training.runs import TrainingRun

# Q-Net's architecture options default to QNetConfig's own values.
QNET_DEFAULTS = {field.name: field.default for field in fields(QNetConfig)}
DEFAULT_CACHE = Path(os.environ.get('BBPOSE_CACHE', Path.home() / '.cache/bbpose/train'))


def add_common_options(parser: argparse.ArgumentParser) -> None:
    """Add ``--dataset``, ``--objects``, ``--cache``, ``--seed`` and ``--threads``."""
    add_dataset_argument(parser)
    add_objects_argument(parser)
    parser.add_argument('--cache', type=Path, default=DEFAULT_CACHE,
                        help='training cache folder (default: $BBPOSE_CACHE or %(default)s)')
    parser.add_argument('--seed', type=int, default=1, help='random seed')
    parser.add_argument('--threads', type=int, default=2, help='torch threads')


def add_budget_options(parser: argparse.ArgumentParser, steps: int = 20000) -> None:
    """Add a training run's folder, length, checkpoints, export, cache shards and device."""
    parser.add_argument('--run-dir', type=Path, required=True,
                        help='run folder: checkpoint (resumed), logs, plot, weights')
    parser.add_argument('--steps', type=int, default=steps,
                        help='total steps (the learning-rate schedule spans them)')
    parser.add_argument('--minutes', type=float, default=None,
                        help='stop after this many minutes (resume later)')
    parser.add_argument('--every', type=int, default=500, help='steps between checkpoints')
    parser.add_argument('--export', type=Path, default=None,
                        help='also copy the weight file here at every checkpoint')
    parser.add_argument('--max-shards', type=int, default=None,
                        help='use only the first N cache shards')
    parser.add_argument('--device', choices=DEVICES, default=None,
                        help='train on the CPU or a CUDA GPU (automatic mixed precision); '
                             'default: cuda when torch sees a GPU, else cpu')


def add_input_size_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--input-size W,H``: the detector's input size a scene cache stores."""
    parser.add_argument('--input-size', type=int_tuple, default=(320, 240), metavar='W,H',
                        help="the detector's input size the frames are stored at; multiples "
                             'of 16 (default 320,240)')


def add_crop_options(parser: argparse.ArgumentParser) -> None:
    """Add ``--crop-size``, ``--context`` and ``--box-sigma`` of a crop cache."""
    parser.add_argument('--crop-size', type=int, default=STORED_CROP_SIZE,
                        help='stored crop side (Q-Net resizes to its own)')
    parser.add_argument('--context', type=float, default=1.2,
                        help="crop side / longest box side (Q-Net's context)")
    parser.add_argument('--box-sigma', type=float, default=0.06,
                        help='box jitter: per-side error / box size')


def training_run(args: argparse.Namespace) -> TrainingRun:
    """Return the TrainingRun of the budget options, ``--seed`` and ``--threads``."""
    from bbpose_ros.core.training.device import training_device
    from bbpose_ros.core.training.runs import TrainingRun
    return TrainingRun(args.run_dir, args.steps, seconds(args), args.seed, args.threads,
                       args.export, args.every, device=training_device(args.device))


def add_init_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--init WEIGHTS``: fine-tune a trained network."""
    parser.add_argument('--init', type=Path, default=None, metavar='WEIGHTS',
                        help='start from this weight file of the same kind, objects and '
                             'architecture instead of ImageNet: fine-tuning')


def add_backbone_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--backbone``: an ImageNet trunk ('lite0') or the plain conv stack."""
    parser.add_argument('--backbone', choices=BACKBONES, default='scratch',
                        help="'lite0': EfficientNet-Lite0 from ImageNet with a small head; "
                             "'scratch': the plain conv stack (default %(default)s)")


def add_backgrounds_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--backgrounds DIR...``: photographs behind the renders."""
    parser.add_argument('--backgrounds', type=Path, nargs='+', default=None, metavar='DIR',
                        help='folders of photographs used as backgrounds 70%% of the time '
                             '(default: procedural backgrounds only)')


def add_table_options(parser: argparse.ArgumentParser) -> None:
    """Add the table style's mesh colour ranges, ``--no-shadows`` and ``--no-clutter``."""
    defaults = TableConfig()
    parser.add_argument('--mesh-brightness-range', type=float_pair, metavar='LOW,HIGH',
                        default=None,
                        help="'table' style: per mesh, a brightness gain drawn log-uniformly "
                             'from this range (default %g,%g: no brightness drawn)'
                             % defaults.brightness_range)
    parser.add_argument('--mesh-color-gain-range', type=float_pair, metavar='LOW,HIGH',
                        default=None,
                        help="'table' style: per mesh, per-channel colour gains drawn from "
                             'this range (default %g,%g)' % defaults.color_gain_range)
    parser.add_argument('--no-shadows', action='store_true',
                        help="'table' style: the lights cast no shadows (the same scenes "
                             'otherwise: for measuring what shadows are worth)')
    parser.add_argument('--no-clutter', action='store_true',
                        help="'table' style: the clutter is drawn, then left out of the "
                             'image (the same scenes otherwise: for measuring what clutter '
                             'is worth)')


def add_qnet_options(parser: argparse.ArgumentParser) -> None:
    """Add Q-Net's architecture, caches, validation and training settings options."""
    parser.add_argument('--crop-size', type=int, default=QNET_DEFAULTS['crop_size'],
                        help='crop side (paper: 48)')
    parser.add_argument('--rotation-target', choices=ROTATION_TARGETS,
                        default=QNET_DEFAULTS['rotation_target'],
                        help='regressed rotation (paper: egocentric)')
    parser.add_argument('--sharing', choices=SHARING_MODES, default=QNET_DEFAULTS['sharing'],
                        help='one trunk with per-object heads, or one network per object')
    parser.add_argument('--channels', type=int_tuple, default=QNET_DEFAULTS['channels'],
                        help='widths of the conv + max-pool stages, comma separated '
                             '(default %(default)s)')
    parser.add_argument('--first-stride', type=int, choices=(1, 2),
                        default=QNET_DEFAULTS['first_stride'],
                        help='stride of the first convolution: 1 (paper), or 2 in place of '
                             'the first max-pool (default %(default)s)')
    parser.add_argument('--hypotheses', type=int, default=QNET_DEFAULTS['hypotheses'],
                        help='quaternions per head, trained winner-takes-all, the best-scored '
                             'one is the output (paper: 1)')
    parser.add_argument('--box-sigma-from', type=Path, default=None,
                        help='a detector weight file: its measured side_sigma is --box-sigma')
    add_extra_cache_option(parser, 'crop')
    add_backbone_option(parser)
    parser.add_argument('--real-val', action='store_true',
                        help="also validate on the dataset's real frames with ground-truth "
                             'boxes (measured only, never trained on)')
    add_settings_options(parser, QNetTrainSettings, TRAINING_TITLE, show_defaults=True)


def add_extra_cache_option(parser: argparse.ArgumentParser, kind: str) -> None:
    """Add ``--extra-cache DIR...``: more caches of ``kind`` ('scene' or 'crop')."""
    parser.add_argument('--extra-cache', type=Path, nargs='+', default=(), metavar='DIR',
                        help=f'more {kind} caches to train on, with the same objects, camera '
                             f'and sizes as --cache')


def table_config(args: argparse.Namespace) -> TableConfig:
    """Return the TableConfig of the table-style render options."""
    given = {'brightness_range': args.mesh_brightness_range,
             'color_gain_range': args.mesh_color_gain_range,
             'shadows': False if args.no_shadows else None,
             'clutter': False if args.no_clutter else None}
    return with_inplane_range(
        TableConfig(**{name: value for name, value in given.items() if value is not None}),
        args)


def refuse_table_options(args: argparse.Namespace) -> None:
    """Raise InputError where the table style's options come with another style."""
    given = [option for option, value in (
        ('--mesh-brightness-range', args.mesh_brightness_range),
        ('--mesh-color-gain-range', args.mesh_color_gain_range),
        ('--no-shadows', args.no_shadows or None),
        ('--no-clutter', args.no_clutter or None)) if value is not None]
    if given:
        raise InputError(f'{", ".join(given)}: for --scene-style table, not '
                         f'{args.scene_style}')


def check_input_size(args: argparse.Namespace) -> None:
    """Raise InputError unless ``--input-size`` is W,H in positive multiples of 16."""
    if len(args.input_size) != 2 or any(side <= 0 or side % 16 for side in args.input_size):
        raise InputError(f'--input-size must be W,H in positive multiples of 16, '
                         f'got {args.input_size}')


def seconds(args: argparse.Namespace) -> float | None:
    """Return the time budget of ``--minutes`` in seconds, or None without one."""
    return None if args.minutes is None else args.minutes * 60.0
