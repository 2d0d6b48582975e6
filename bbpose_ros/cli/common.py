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

"""Argument helpers shared by the subcommands."""

import argparse
from collections.abc import Collection, Sequence
from dataclasses import replace
import os
from pathlib import Path
from typing import TypeVar

from bbpose_ros.core.data.bop import DEFAULT_DATASET
from bbpose_ros.core.util.errors import InputError

Config = TypeVar('Config')
Item = TypeVar('Item')
SCENE_STYLES = ('random', 'table')


def add_dataset_argument(parser: argparse.ArgumentParser) -> None:
    """Add ``--dataset DIR`` (a BOP folder; default ../shared/datasets/lmo)."""
    parser.add_argument('--dataset', type=Path,
                        default=Path(os.environ.get('BBPOSE_DATASET', DEFAULT_DATASET)),
                        help='BOP dataset folder (default: $BBPOSE_DATASET or %(default)s)')


def add_objects_argument(parser: argparse.ArgumentParser) -> None:
    """Add ``--objects a,b,c`` (default: every object of the dataset)."""
    parser.add_argument('--objects', type=lambda text: [n for n in text.split(',') if n],
                        default=None, help='comma-separated object names (default: all)')


def add_scene_style_argument(parser: argparse.ArgumentParser) -> None:
    """Add ``--scene-style random|table``: the kind of synthetic scenes rendered."""
    parser.add_argument('--scene-style', choices=SCENE_STYLES, default='random',
                        help="'random': objects floating at random poses over a background "
                             "among distractors; 'table': objects resting on a textured "
                             'table among clutter, lit with shadows and highlights, seen '
                             'from above like LM-O (default %(default)s)')


def add_inplane_argument(parser: argparse.ArgumentParser) -> None:
    """Add ``--inplane-range-deg LOW,HIGH`` (the synthetic objects' roll; default: any)."""
    parser.add_argument('--inplane-range-deg', type=float_pair, default=None,
                        metavar='LOW,HIGH',
                        help='roll of the rendered objects about the optical axis, degrees, '
                             "0 when the model's z axis points up in the image, e.g. "
                             '--inplane-range-deg=-60,60 for upright objects (default: any)')


def with_inplane_range(config: Config, args: argparse.Namespace) -> Config:
    """Return the SynthConfig ``config`` with ``--inplane-range-deg`` applied when given."""
    if args.inplane_range_deg is None:
        return config
    return replace(config, inplane_range_deg=args.inplane_range_deg)


def float_pair(text: str) -> tuple[float, float]:
    """Parse 'A,B' into two floats (an argparse type)."""
    try:
        low, high = (float(x) for x in text.split(','))
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected LOW,HIGH, got {text!r}')
    return low, high


def add_blocks_argument(parser: argparse.ArgumentParser) -> None:
    """Add ``--blocks 1,3,5`` and ``--block-size N``: whole blocks of consecutive frames."""
    parser.add_argument('--blocks', type=_block_numbers, default=None, metavar='K,K,...',
                        help='use only these blocks of --block-size consecutive frames (in '
                             'scene and image id order, first block 1): e.g. adapt on '
                             '1,3,5 and score 2,4, so that no scored frame neighbours an '
                             'adapted one (default: all frames)')
    parser.add_argument('--block-size', type=int, default=20,
                        help='frames a block of --blocks (default %(default)s)')


def in_blocks(items: Sequence[Item], blocks: Collection[int] | None,
              size: int) -> list[Item]:
    """Keep the ``items`` of the 1-based ``blocks`` of ``size`` consecutive ones (None: all)."""
    if blocks is None:
        return list(items)
    if size < 1:
        raise InputError(f'--block-size must be at least 1, got {size}')
    count = -(-len(items) // size)
    outside = sorted(b for b in blocks if not 1 <= b <= count)
    if outside:
        raise InputError(f'--blocks {outside[0]}: the {len(items)} frames make {count} '
                         f'blocks of {size}')
    return [item for k, item in enumerate(items) if k // size + 1 in blocks]


def _block_numbers(text: str) -> set[int]:
    try:
        return {int(part) for part in text.split(',') if part}
    except ValueError:
        raise argparse.ArgumentTypeError(f'blocks are comma-separated numbers, got {text!r}')


def add_frames_argument(parser: argparse.ArgumentParser) -> None:
    """Add ``--max-frames N`` to evaluate or convert only the first N frames."""
    parser.add_argument('--max-frames', type=int, default=None,
                        help='use only the first N frames (default: all)')


def rgb(text: str) -> tuple[int, int, int]:
    """Parse 'R,G,B' (0-255 each) into a tuple (an argparse type)."""
    try:
        values = tuple(int(part) for part in text.split(','))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(0 <= value <= 255 for value in values):
        raise argparse.ArgumentTypeError(f'expected R,G,B integers 0-255, got {text!r}')
    return values


def add_mesh_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--mesh`` (required), ``--units``, ``--color`` and ``--max-faces`` of a new mesh."""
    from bbpose_ros.core.data.mesh_check import MAX_FACES, UNITS
    parser.add_argument('--mesh', required=True, type=Path,
                        help='mesh file (PLY, OBJ, STL, GLB; a texture becomes vertex colours)')
    parser.add_argument('--units', choices=tuple(UNITS), default='mm',
                        help="the file's length unit (default %(default)s, as BOP's)")
    parser.add_argument('--color', type=rgb, default=None, metavar='R,G,B',
                        help='paint the whole mesh this colour, 0-255 each (needed when it has '
                             'no colours)')
    parser.add_argument('--max-faces', type=int, default=MAX_FACES,
                        help='decimate meshes with more faces (default %(default)s)')
