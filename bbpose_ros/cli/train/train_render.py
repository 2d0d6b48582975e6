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

"""``bbpose train render``: synthetic scenes -> a scene cache (the detector trains on it)."""

import argparse

from bbpose_ros.cli.common import add_inplane_argument, add_scene_style_argument, \
    with_inplane_range
from bbpose_ros.cli.train.arguments import (add_backgrounds_option, add_common_options,
                                            add_input_size_option, add_table_options,
                                            check_input_size, refuse_table_options,
                                            table_config)
from bbpose_ros.cli.train.inputs import cache_camera, other_models, photos


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``bbpose train render``."""
    render = subparsers.add_parser('render', help='render a training cache')
    add_common_options(render)
    render.add_argument('--scenes', type=int, default=6000,
                        help='scenes to render, rounded up to whole shards of the cache '
                             '(default %(default)s)')
    render.add_argument('--workers', type=int, default=2, help='rendering processes')
    add_scene_style_argument(render)
    add_input_size_option(render)
    add_backgrounds_option(render)
    add_inplane_argument(render)
    add_table_options(render)
    render.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Render the training cache."""
    from bbpose_ros.core.data.models import load_bop_models
    from bbpose_ros.core.synth import SynthConfig, SyntheticScenes
    from bbpose_ros.core.training.cache import build_cache
    check_input_size(args)
    camera = cache_camera(args.dataset)
    models = load_bop_models(args.dataset, args.objects)
    if args.scene_style == 'table':
        from bbpose_ros.core.synth.table_scenes import TableScenes
        scenes = TableScenes(models, camera, seed=args.seed, config=table_config(args),
                             distractor_models=other_models(args, models),
                             backgrounds=photos(args))
    else:
        refuse_table_options(args)
        scenes = SyntheticScenes(models, camera, seed=args.seed,
                                 config=with_inplane_range(SynthConfig(), args),
                                 backgrounds=photos(args))
    build_cache(scenes, args.cache, args.scenes, args.input_size, workers=args.workers)
    return 0
