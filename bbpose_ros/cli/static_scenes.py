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


"""``bbpose static-scenes``: write a labelled BOP split as static scenes with camera poses."""

import argparse
import json
import os
from pathlib import Path
import shutil

import numpy as np
from tqdm import tqdm

from bbpose_ros.cli.common import add_dataset_argument, float_pair
from bbpose_ros.core.data.bop import bop_camera_fields, BopDataset, read_json
from bbpose_ros.core.eval.static_stretches import camera_poses, noisy_pose, static_stretches
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.core.util.files import atomic_output


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the ``static-scenes`` subcommand."""
    parser = subparsers.add_parser(
        'static-scenes', help='an evaluation tool: a labelled split as static scenes with '
                              'camera poses, for bbpose eval --fuse',
        description='An evaluation tool: it reads the ground truth. Consecutive frames whose '
                    'annotated objects keep every pairwise distance (within --tolerance-mm) '
                    'become one BOP scene; each frame gets a camera pose in its scene '
                    "(BOP's cam_R_w2c / cam_t_w2c, world: the scene's first camera), fitted "
                    'to its annotated objects, with --camera-noise standing in for a '
                    "robot's TF error. The map (bbpose eval --fuse) then reads the images and "
                    'these camera poses, never the ground truth. Images are hard-linked (or '
                    'copied), the annotations kept as they are.')
    add_dataset_argument(parser)
    parser.add_argument('--split', default='test', help='split to read (default %(default)s)')
    parser.add_argument('--out', type=Path, required=True,
                        help='the BOP folder to write (must not exist)')
    parser.add_argument('--tolerance-mm', type=float, default=5.0,
                        help='most change of a distance between two objects within a static '
                             'scene, millimetres (default %(default)s)')
    parser.add_argument('--camera-noise', type=float_pair, default=None, metavar='MM,DEG',
                        help='add a TF-like error to each camera pose: RMS position error MM '
                             'millimetres, RMS rotation error DEG degrees (default: none)')
    parser.add_argument('--seed', type=int, default=0,
                        help='seed of --camera-noise (default %(default)s)')
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Write the static scenes; returns the exit code."""
    if args.out.exists():
        raise InputError(f'{args.out} exists; pick a new folder')
    if args.camera_noise is not None and min(args.camera_noise) < 0:
        raise InputError('--camera-noise: MM and DEG must be >= 0')
    dataset = BopDataset(args.dataset, args.split)
    models = dataset.load_models()
    stretches = static_stretches(dataset.frames(), args.tolerance_mm * 1e-3)
    rng = np.random.default_rng(args.seed)
    with atomic_output(args.out) as out:
        for name in ('camera.json', 'models', 'models_eval', 'models_info.json'):
            source = args.dataset / name
            if source.is_dir():
                shutil.copytree(source, out / name)
            elif source.is_file():
                out.mkdir(parents=True, exist_ok=True)
                shutil.copy2(source, out / name)
        for scene_id, stretch in enumerate(tqdm(stretches, desc='scenes', unit='scene'), 1):
            scene_dir = out / args.split / f'{scene_id:06d}'
            (scene_dir / 'rgb').mkdir(parents=True)
            source_dir = dataset.split_dir / f'{stretch[0].scene_id:06d}'
            gts = read_json(source_dir / 'scene_gt.json')
            infos = read_json(source_dir / 'scene_gt_info.json')
            cameras = read_json(source_dir / 'scene_camera.json')
            scene_gt, scene_info, scene_camera = {}, {}, {}
            for frame, pose in zip(stretch, camera_poses(stretch, models)):
                key = str(frame.image_id)
                if args.camera_noise is not None:
                    pose = noisy_pose(pose, *args.camera_noise, rng)
                scene_gt[key], scene_info[key] = gts[key], infos[key]
                scene_camera[key] = {**cameras[key], **bop_camera_fields(pose)}
                _link_or_copy(frame.image_path, scene_dir / 'rgb' / frame.image_path.name)
            for name, data in (('scene_gt.json', scene_gt), ('scene_gt_info.json', scene_info),
                               ('scene_camera.json', scene_camera)):
                (scene_dir / name).write_text(json.dumps(data))
    multi = [s for s in stretches if len(s) > 1]
    print(f'{len(stretches)} static scenes written to {args.out}: {len(multi)} of 2 or more '
          f'frames hold {sum(len(s) for s in multi)} frames, {len(stretches) - len(multi)} '
          'frames stand alone')
    return 0


def _link_or_copy(source, target):
    try:
        os.link(source, target)
    except OSError:
        shutil.copy2(source, target)
