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

"""``bbpose train render-crops``: object-centred crops -> a crop cache (Q-Net, dense net)."""

import argparse

from bbpose_ros.cli.common import add_inplane_argument, SCENE_STYLES, with_inplane_range
from bbpose_ros.cli.train.arguments import (add_backgrounds_option, add_common_options,
                                            add_crop_options, add_table_options,
                                            refuse_table_options, table_config)
from bbpose_ros.cli.train.inputs import cache_camera, other_models, photos
from bbpose_ros.core.util.errors import InputError


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``bbpose train render-crops``."""
    crops = subparsers.add_parser('render-crops', help='render a Q-Net crop cache')
    add_common_options(crops)
    crops.add_argument('--crops', type=int, default=80000,
                       help="crops to render ('random' style)")
    crops.add_argument('--scene-style', choices=SCENE_STYLES, default='random',
                       help="'random': each crop rendered alone around a floating object; "
                            "'table': whole table-top scenes (as 'bbpose train render "
                            "--scene-style table'), a crop cut around every target at least "
                            '15 %% visible (default %(default)s)')
    crops.add_argument('--scenes', type=int, default=None,
                       help="table scenes to render ('table' style; each gives about 5 crops)")
    crops.add_argument('--workers', type=int, default=2, help='rendering processes')
    crops.add_argument('--dense-size', type=int, default=0, metavar='M',
                       help="also store the dense head's targets (model coordinates, visible "
                            'and amodal masks) on an M x M grid per crop; M must divide twice '
                            'the crop size (default 0: none, a version-1 cache)')
    add_crop_options(crops)
    add_backgrounds_option(crops)
    add_inplane_argument(crops)
    add_table_options(crops)
    crops.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Render the Q-Net crop cache."""
    from bbpose_ros.core.data.models import load_bop_models
    from bbpose_ros.core.training.crop_cache import build_crop_cache
    camera = cache_camera(args.dataset)
    models = load_bop_models(args.dataset, args.objects)
    if args.scene_style == 'table':
        from bbpose_ros.core.synth.table_crops import TableCrops
        if args.scenes is None or args.scenes < 1:
            raise InputError('--scene-style table needs --scenes N (N >= 1): the table scenes '
                             'to render')
        scenes = TableCrops(models, camera, seed=args.seed,
                            config=table_config(args),
                            distractor_models=other_models(args, models),
                            backgrounds=photos(args), crop_size=args.crop_size,
                            context=args.context, box_sigma=args.box_sigma,
                            dense_size=args.dense_size)
        count = args.scenes
    else:
        from bbpose_ros.core.synth.crop_scenes import CROP_SYNTH_CONFIG, CropScenes
        if args.scenes is not None:
            raise InputError("--scenes is for --scene-style table; 'random' counts --crops")
        refuse_table_options(args)
        scenes = CropScenes(models, camera, seed=args.seed,
                            config=with_inplane_range(CROP_SYNTH_CONFIG, args),
                            crop_size=args.crop_size, context=args.context,
                            box_sigma=args.box_sigma, backgrounds=photos(args),
                            dense_size=args.dense_size)
        count = args.crops
    build_crop_cache(scenes, args.cache, count, workers=args.workers)
    return 0
