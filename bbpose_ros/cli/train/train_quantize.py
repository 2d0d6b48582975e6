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

"""``bbpose train quantize``: the int8 graph of the detector or Q-Net, calibrated on renders."""

import argparse
from pathlib import Path

from bbpose_ros.core.util.errors import InputError


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``bbpose train quantize``."""
    quantize = subparsers.add_parser(
        'quantize', help='quantise the detector or Q-Net to int8',
        description='Write the int8 graph of a detector or Q-Net weight file (ONNX Runtime '
                    'static quantisation), its activation ranges measured on renders of a '
                    'scene cache; the node runs it with inference_precision int8 (or auto).')
    quantize.add_argument('--network', choices=('detector', 'qnet'), required=True,
                          help='which network')
    quantize.add_argument('--weights', type=Path, default=None,
                          help='float weight file (default: the shipped detector.pt or '
                               'qnet.pt)')
    quantize.add_argument('--cache', type=Path, required=True,
                          help='scene cache whose renders calibrate (never real evaluation '
                               'frames)')
    quantize.add_argument('--inputs', type=int, default=None,
                          help='calibration inputs: frames for the detector (default 32), '
                               'instance crops for Q-Net (default 256)')
    quantize.add_argument('--out', type=Path, default=None,
                          help='the .onnx to write (default: <weights stem>_int8.onnx beside '
                               'the weights)')
    quantize.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Write the int8 graph of the detector or Q-Net, calibrated on a scene cache."""
    import shlex
    import sys

    from bbpose_ros.core.inference.int8_graphs import int8_graph_path
    from bbpose_ros.core.inference.weights import (DEFAULT_DETECTOR_WEIGHTS,
                                                   DEFAULT_QNET_WEIGHTS, load_network)
    from bbpose_ros.core.training import quantization
    from bbpose_ros.core.training.cache import TrainingCache
    count = args.inputs or (32 if args.network == 'detector' else 256)
    if count < 1:
        raise InputError(f'--inputs must be at least 1, got {count}')
    default = DEFAULT_DETECTOR_WEIGHTS if args.network == 'detector' else DEFAULT_QNET_WEIGHTS
    weights = args.weights or default
    config = load_network(weights, args.network).config
    cache = TrainingCache(args.cache, max_shards=1)
    if args.network == 'detector':
        inputs = (quantization.calibration_images(cache.images, config.input_size, count),)
    else:
        inputs = quantization.calibration_crops(cache, config, count)
    out = quantization.quantize_network(weights, args.network, inputs,
                                        args.out or int8_graph_path(weights),
                                        command=shlex.join(['bbpose', *sys.argv[1:]]))
    print(f'int8 {args.network} graph written to {out} ({out.stat().st_size / 1e6:.2f} MB, '
          f'{len(inputs[0])} calibration inputs from {args.cache})')
    return 0
