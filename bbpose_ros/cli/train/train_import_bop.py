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
``bbpose train import-bop``: annotated images of a BOP split -> a scene or crop cache.

PBR renders, real frames, one's own captures; never the evaluation frames.
"""

import argparse
import os
from pathlib import Path

from bbpose_ros.cli.train.arguments import (add_common_options, add_crop_options,
                                            add_input_size_option, check_input_size)
from bbpose_ros.cli.train.inputs import cache_camera
from bbpose_ros.core.data.bop import DEFAULT_DATASET
from bbpose_ros.core.util.errors import InputError


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``bbpose train import-bop``."""
    bop = subparsers.add_parser(
        'import-bop', help='fill a training cache from annotated BOP images',
        description='Fill a scene cache (detector) or a crop cache (Q-Net) from the annotated '
                    'images of a BOP split: PBR renders such as train_pbr, real frames, your '
                    'own captures. Meshes and the cache camera come from --dataset. The '
                    "dataset's evaluation frames are refused.")
    add_common_options(bop)
    bop.add_argument('--images', type=Path, required=True,
                     help='BOP folder holding camera.json and the split')
    bop.add_argument('--split', required=True, help='split folder name, e.g. train_pbr')
    bop.add_argument('--kind', choices=('scenes', 'crops'), default='scenes',
                     help="'scenes': the detector's scene cache (Q-Net trains on it too); "
                          "'crops': a Q-Net crop cache (default %(default)s)")
    bop.add_argument('--workers', type=int, default=2, help='importing processes')
    add_input_size_option(bop)
    add_crop_options(bop)
    bop.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Fill a scene or crop cache from the annotated images of a BOP split."""
    from bbpose_ros.core.data.models import load_bop_models
    from bbpose_ros.core.training.bop_import import (BopImages, import_crop_cache,
                                                     import_scene_cache)
    if args.kind == 'scenes':
        check_input_size(args)
    elif args.crop_size < 8 or args.context <= 0 or args.box_sigma < 0:
        raise InputError(f'--crop-size must be at least 8, --context positive and --box-sigma '
                         f'non-negative, got {args.crop_size}, {args.context}, '
                         f'{args.box_sigma}')
    if args.workers < 1:
        raise InputError(f'--workers must be at least 1, got {args.workers}')
    images = BopImages(args.images, args.split, _evaluation_images(args))
    camera = cache_camera(args.dataset)
    models = load_bop_models(args.dataset, args.objects)
    if args.kind == 'scenes':
        count = import_scene_cache(images, args.cache, camera, models, args.input_size,
                                   workers=args.workers)
    else:
        count = import_crop_cache(images, args.cache, camera, models, args.crop_size,
                                  args.context, args.box_sigma, seed=args.seed,
                                  workers=args.workers)
    print(f'{args.cache}: {count} {"scenes" if args.kind == "scenes" else "crops"} from '
          f'{len(images.frames)} images of {args.images} split {args.split}')
    return 0


def _evaluation_images(args):
    """
    Images no cache may import: the test frames of ``--dataset`` and of the default dataset.

    They are what ``--real-val``, ``bbpose eval`` and ``replay-eval`` score.
    """
    from bbpose_ros.core.data.bop import BopDataset
    default = Path(os.environ.get('BBPOSE_DATASET', DEFAULT_DATASET))
    paths = []
    for root in {Path(args.dataset).resolve(), default.resolve()}:
        if (root / 'test').is_dir() and (root / 'camera.json').is_file():
            paths += [frame.image_path for frame in BopDataset(root).frames()]
    return paths
