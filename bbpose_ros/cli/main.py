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
The ``bbpose`` command: one entry point with subcommands, like ``ros2 bag ...``.

Each subcommand module offers ``add_parser(subparsers)``, which registers its parser and
sets ``func(args) -> exit code``. Bad input (InputError) becomes one clear line on stderr
and exit code 2; nothing half-written is left behind by the subcommands.
"""

import argparse
from collections.abc import Sequence
import importlib
import sys

from bbpose_ros import __version__
from bbpose_ros.core.util.errors import InputError

SUBCOMMANDS = ('make_bag', 'eval', 'synth', 'check_mesh', 'train', 'play', 'replay_eval',
               'bench', 'docs', 'compare', 'pose_spread', 'add_object', 'adapt', 'score_labels',
               'static_scenes')


def build_parser() -> argparse.ArgumentParser:
    """Build the argument parser with every subcommand registered."""
    parser = argparse.ArgumentParser(
        prog='bbpose', description='6D object pose from one RGB image: tools of bbpose_ros.')
    parser.add_argument('--version', action='version', version=f'%(prog)s {__version__}')
    subparsers = parser.add_subparsers(dest='command', metavar='COMMAND', required=True)
    for name in SUBCOMMANDS:
        importlib.import_module(f'bbpose_ros.cli.{name}').add_parser(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``bbpose``; returns the exit code (0 ok, 2 bad input, 130 interrupted)."""
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except InputError as err:
        print(f'bbpose {args.command}: error: {err}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'bbpose {args.command}: interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
