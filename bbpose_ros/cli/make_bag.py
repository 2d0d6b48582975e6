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

"""``bbpose make-bag``: turn a BOP scene into a rosbag2 for replay and tests."""

import argparse
from pathlib import Path
import time

from bbpose_ros.bags.topics import DEFAULT_FRAME_ID
from bbpose_ros.bags.writer import STORAGE, write_bop_bag
from bbpose_ros.cli.common import add_dataset_argument, add_frames_argument
from bbpose_ros.core.data.bop import BopDataset
from bbpose_ros.core.data.compressed_image import DEFAULT_JPEG_QUALITY
from bbpose_ros.core.util.errors import InputError


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the ``make-bag`` subcommand."""
    parser = subparsers.add_parser(
        'make-bag', help='write BOP frames as a rosbag2 (images, camera info, ground truth)',
        description='Write the frames of a BOP dataset as a rosbag2: /camera/image_raw (rgb8), '
                    'or with --compressed /camera/image_raw/compressed (JPEG '
                    'sensor_msgs/CompressedImage, as image_transport records a camera), '
                    '/camera/camera_info and /ground_truth/<object>/pose (metres).')
    add_dataset_argument(parser)
    parser.add_argument('--out', type=Path, required=True, help='bag folder to create')
    parser.add_argument('--scene', type=int, action='append', default=None,
                        help='scene id (repeatable; default: all scenes)')
    add_frames_argument(parser)
    parser.add_argument('--split', default='test',
                        help="the dataset's split folder, e.g. train_synth for `bbpose synth` "
                             'output (default %(default)s)')
    parser.add_argument('--rate', type=float, default=10.0,
                        help='frames per second of the stamps (default %(default)s)')
    parser.add_argument('--start-stamp', type=float, default=None,
                        help='stamp of the first frame in seconds (default: now)')
    parser.add_argument('--frame-id', default=DEFAULT_FRAME_ID,
                        help='optical frame of the camera (default %(default)s)')
    parser.add_argument('--storage', choices=sorted(STORAGE), default='mcap',
                        help='rosbag2 storage (default %(default)s)')
    parser.add_argument('--compressed', action='store_true',
                        help="write the images as image_transport's compressed transport "
                             'does: JPEG sensor_msgs/CompressedImage on '
                             '/camera/image_raw/compressed (replay-eval then runs the node '
                             'with image_transport compressed)')
    parser.add_argument('--jpeg-quality', type=int, default=None,
                        help=f'with --compressed: JPEG quality, 1 .. 100 (default '
                             f"{DEFAULT_JPEG_QUALITY}, image_transport's)")
    parser.add_argument('--min-visib', type=float, default=0.1,
                        help='write ground truth for instances at least this visible '
                             '(default %(default)s, what bbpose eval counts)')
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Write the bag; returns the exit code."""
    if args.jpeg_quality is not None and not args.compressed:
        raise InputError('--jpeg-quality is for --compressed bags')
    quality = DEFAULT_JPEG_QUALITY if args.jpeg_quality is None else args.jpeg_quality
    frames = BopDataset(args.dataset, args.split).frames(args.scene)[:args.max_frames]
    start = time.time() if args.start_stamp is None else args.start_stamp
    count = write_bop_bag(frames, args.out, rate_hz=args.rate,
                          start_stamp_ns=int(round(start * 1e9)), frame_id=args.frame_id,
                          storage=args.storage, min_visib=args.min_visib,
                          compressed=args.compressed, jpeg_quality=quality)
    kind = f' (JPEG, quality {quality})' if args.compressed else ''
    print(f'wrote {count} frames{kind} to {args.out}')
    return 0
