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
``bbpose adapt``: adapt the networks to the user's scene from an unlabelled recording.

The pipeline labels the recording itself: a careful teacher finds and refines every pose,
gates keep the labels it can trust, and the detector's heads and Q-Net's head rows learn
from them (``core.adaptation``). The output folder holds weight files, int8 graphs and a
``params.yaml`` the node starts with, like ``bbpose add-object``'s.
"""

import argparse
from pathlib import Path
import shlex
import sys

from bbpose_ros.bags import topics
from bbpose_ros.cli.common import add_blocks_argument, add_dataset_argument, in_blocks
from bbpose_ros.cli.settings_options import add_settings_options, settings_made
from bbpose_ros.core.adaptation.adapt_settings import AdaptSettings

PARAMS_HEADER = ('# bbpose_node parameters written by bbpose adapt: the base parameters with the\n'
                 '# weights adapted to the recording (config/bbpose.yaml documents each one).\n')


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``bbpose adapt``."""
    parser = subparsers.add_parser(
        'adapt', help='adapt the networks to your scene from an unlabelled recording',
        description='Label a recording of your camera with the pipeline itself (a careful '
                    'teacher: every candidate refined, the dense net beside Q-Net) and '
                    "retrain the detector's heads and Q-Net's head rows on the labels it "
                    'trusts. No ground truth is read. Writes to --out: detector.pt, qnet.pt '
                    'and their int8 graphs, params.yaml (start the node with it), '
                    'pseudo_labels/ (a BOP split), preview.png and report.json. Rerun the '
                    'same command to resume.')
    parser.add_argument('--bag', type=Path, default=None,
                        help='a rosbag2 of your camera: sensor_msgs/Image and CameraInfo, as '
                             '`ros2 bag record` or `bbpose make-bag` writes them (default: the '
                             'images of --dataset)')
    parser.add_argument('--split', default='test',
                        help='without --bag, the split of --dataset whose images to adapt on '
                             '(its ground-truth files, if any, are not read; default %(default)s)')
    parser.add_argument('--image-topic', default=topics.IMAGE_TOPIC,
                        help='image topic of --bag (default %(default)s)')
    parser.add_argument('--camera-info-topic', default=topics.CAMERA_INFO_TOPIC,
                        help='CameraInfo topic of --bag (default %(default)s)')
    parser.add_argument('--params', type=Path, default=None,
                        help="the node's parameters file whose weights and settings to adapt "
                             '(default: config/bbpose.yaml with the meshes of --dataset; e.g. '
                             "bbpose add-object's params.yaml)")
    add_dataset_argument(parser)
    add_blocks_argument(parser)
    parser.add_argument('--out', required=True, type=Path, help='output folder (resumable)')
    parser.add_argument('--threads', type=int, default=None,
                        help='torch threads (default: all cores)')
    add_settings_options(parser, AdaptSettings, 'adaptation settings (recorded in report.json)',
                         names=('rounds', 'seed', 'map_labels'), show_defaults=True)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run ``bbpose adapt``; returns the exit status."""
    import torch

    from bbpose_ros.core.adaptation.adapt_stages import Adaptation
    from bbpose_ros.core.adaptation.frames import bag_frames, dataset_frames
    from bbpose_ros.core.data.models import load_bop_models
    from bbpose_ros.core.inference.weights import (DEFAULT_DENSE_WEIGHTS,
                                                   DEFAULT_DETECTOR_WEIGHTS,
                                                   DEFAULT_QNET_WEIGHTS)
    from bbpose_ros.core.pipeline.loader import WeightFiles
    from bbpose_ros.ros.params import read_config
    from bbpose_ros.ros.params_file import (package_config_file, pipeline_values,
                                            read_params_file, write_params_file)

    if args.threads:
        torch.set_num_threads(args.threads)
    params = args.params or package_config_file('bbpose.yaml')
    overrides = [] if args.params else [f'dataset_dir:={args.dataset.resolve()}']
    values = read_params_file(params, overrides)
    config = read_config(values)
    base = WeightFiles(config.detector_weights or DEFAULT_DETECTOR_WEIGHTS,
                       config.qnet_weights or DEFAULT_QNET_WEIGHTS,
                       config.dense_weights or DEFAULT_DENSE_WEIGHTS)
    if args.bag is not None:
        from bbpose_ros.bags.reader import read_bag_frames
        frames = bag_frames(read_bag_frames(args.bag, args.image_topic,
                                            args.camera_info_topic), args.image_topic)
    else:
        frames = dataset_frames(args.dataset, args.split)
    frames = in_blocks(frames, args.blocks, args.block_size)
    settings = settings_made(AdaptSettings, args)
    models = load_bop_models(config.dataset_dir, list(config.objects))
    print(f'adapting {", ".join(models)} on {len(frames)} frames into {args.out}')
    command = shlex.join(['bbpose'] + sys.argv[1:])
    adaptation = Adaptation(frames, models, config.options, base, args.out, settings,
                            command=command)
    report = adaptation.run()
    write_params_file(args.out / 'params.yaml',
                      dict(values, **pipeline_values(adaptation.pipeline_files())), PARAMS_HEADER)
    labels = report['labels'][f'round{settings.rounds}']
    print('labels of the last round: ' + ', '.join(f'{name} {c["accepted"]}'
                                                   for name, c in labels.items()))
    print(f'done in {report["seconds"]["total"] / 60:.1f} min (peak memory '
          f'{report["peak_rss_mb"] / 1024:.1f} GB); run the node with:\n'
          f'  .venv/bin/bbpose_node --ros-args --params-file {args.out / "params.yaml"}')
    return 0
