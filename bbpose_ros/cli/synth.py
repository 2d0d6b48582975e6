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
``bbpose synth``: render synthetic training images of a dataset's objects, BOP format.

Output (see ``bbpose_ros.core.synth.export``): ``camera.json``, ``train_synth/000000/``
with images, visible masks and ground truth, ``models/`` (a copy of the dataset's: meshes,
models_info.json, the names table), ``previews/`` with boxes drawn, and ``synth_info.json``
(seed, objects, settings): a BOP dataset of its own, which ``bbpose eval --split
train_synth`` scores. With ``--camera-path`` the images are the frames of one table scene
seen by a moving camera (``core.synth.camera_path``), for a bag (``make-bag --split``).
The folder appears only when complete: it is written under a temporary name next to it
and renamed at the end.
"""

import argparse
from dataclasses import asdict
from pathlib import Path
import shutil

from tqdm import tqdm

from bbpose_ros.cli.common import add_dataset_argument, add_inplane_argument, \
    add_scene_style_argument, with_inplane_range
from bbpose_ros.core.data.bop import load_camera
from bbpose_ros.core.data.models import load_bop_models, names_source, resolve_object_names
from bbpose_ros.core.synth import SynthConfig, SyntheticScenes
from bbpose_ros.core.synth.camera_path import orbit_path
from bbpose_ros.core.synth.export import BopSceneWriter, draw_preview, write_json
from bbpose_ros.core.synth.table_config import TableConfig
from bbpose_ros.core.synth.table_scenes import TableScenes
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.core.util.files import atomic_output, write_rgb_png

# The camera path's settings when not given: a camera's rate, a slow turn, a hand's bob.
PATH_DEFAULTS = {'rate': 30.0, 'orbit_speed': 20.0, 'bob': 0.02}


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the ``synth`` subcommand on an argparse subparsers object; return it."""
    parser = subparsers.add_parser(
        'synth', help='render synthetic training images with ground truth (BOP format)',
        description="Render synthetic scenes of a BOP dataset's object meshes (random "
                    'poses, distractors, backgrounds and camera effects, or table-top scenes '
                    'as the shipped networks train on) with their exact ground truth.')
    add_dataset_argument(parser)
    parser.add_argument('--out', required=True, type=Path,
                        help='output folder (must not exist yet)')
    parser.add_argument('--count', required=True, type=int, help='number of images')
    parser.add_argument('--seed', type=int, default=0,
                        help='random seed; image i of a seed is always the same (default 0)')
    parser.add_argument('--objects', default='',
                        help='comma-separated target objects, e.g. ape,can (default all); '
                             "the dataset's other objects appear as unlabelled distractors")
    add_scene_style_argument(parser)
    add_inplane_argument(parser)
    parser.add_argument('--previews', type=int, default=8,
                        help='number of preview images with boxes drawn (default 8)')
    path = parser.add_argument_group(
        'camera path (with --scene-style table): one scene seen by a moving camera, the '
        '--count images its frames at --rate, for `make-bag --split train_synth --rate`')
    path.add_argument('--camera-path', action='store_true',
                      help="render the seed's first table scene from a camera circling what "
                           'it looks at, frame by frame')
    path.add_argument('--rate', type=float, default=None,
                      help=f'frames per second of the path (default {PATH_DEFAULTS["rate"]})')
    path.add_argument('--orbit-speed', type=float, default=None,
                      help='degrees per second the camera circles (default '
                           f'{PATH_DEFAULTS["orbit_speed"]})')
    path.add_argument('--bob', type=float, default=None,
                      help='metres the camera moves up and down, at 0.5 Hz (default '
                           f'{PATH_DEFAULTS["bob"]})')
    path.add_argument('--move', type=_object_shift, default=None, metavar='OBJECT:DX,DY',
                      help='from the middle of the path on, that target object stands moved '
                           'by DX, DY metres on the table (a robot moved it between two '
                           "looks: the map's test); every frame carries its exact camera "
                           'pose either way')
    parser.set_defaults(func=run)
    return parser


def _object_shift(text: str) -> tuple[str, tuple[float, float]]:
    """Parse 'OBJECT:DX,DY' (an argparse type)."""
    name, _, shift = text.partition(':')
    try:
        dx, dy = (float(value) for value in shift.split(','))
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected OBJECT:DX,DY, got {text!r}')
    return name, (dx, dy)


def run(args: argparse.Namespace) -> int:
    """Run ``bbpose synth``; returns the exit status, bad input raises InputError."""
    if args.count < 1:
        raise InputError(f'--count must be at least 1, got {args.count}')
    if args.seed < 0:
        raise InputError(f'--seed must be non-negative, got {args.seed}')
    if args.previews < 0:
        raise InputError(f'--previews must be non-negative, got {args.previews}')
    out = Path(args.out)
    if out.exists():
        raise InputError(f'output folder already exists: {out} (choose a new one)')
    if not Path(args.dataset).is_dir():
        raise InputError(f'dataset folder not found: {args.dataset}')
    camera = load_camera(args.dataset)
    models = load_bop_models(args.dataset)
    requested = [name.strip() for name in args.objects.split(',') if name.strip()]
    targets = resolve_object_names(requested, models, names_source(args.dataset))
    distractors = {name: model for name, model in models.items() if name not in targets}
    target_models = {name: models[name] for name in targets}
    if args.camera_path and args.scene_style != 'table':
        raise InputError('--camera-path needs --scene-style table')
    for name, default in PATH_DEFAULTS.items():
        if getattr(args, name) is not None and not args.camera_path:
            raise InputError(f'--{name.replace("_", "-")} is for --camera-path')
        if getattr(args, name) is None:
            setattr(args, name, default)
    if args.move is not None and (not args.camera_path or args.move[0] not in targets):
        raise InputError(f'--move {args.move[0]}: needs --camera-path and one of the target '
                         f'objects ({", ".join(targets)})')
    if args.scene_style == 'table':
        config = with_inplane_range(TableConfig(), args)
        scenes = TableScenes(target_models, camera, args.seed, config, distractors)
    else:
        config = with_inplane_range(SynthConfig(), args)
        scenes = SyntheticScenes(target_models, camera, args.seed, config, distractors)
    try:
        with atomic_output(out) as staging:
            staging.mkdir()
            shutil.copytree(Path(args.dataset) / 'models', staging / 'models')
            _write(scenes, models, staging, args, targets, distractors, config)
    finally:
        scenes.close()
    print(f'wrote {args.count} {args.scene_style} images of {", ".join(targets)} to {out} '
          f'(boxes drawn on the first {min(args.previews, args.count)} in {out / "previews"}; '
          f'bbpose eval --dataset {out} --split train_synth scores them)')
    return 0


def _write(scenes, models, root, args, targets, distractors, config):
    """Render and write all samples, previews and settings under ``root``."""
    writer = BopSceneWriter(root, scenes.camera,
                            {name: model.obj_id for name, model in models.items()})
    (root / 'previews').mkdir()
    path = None
    if args.camera_path:
        path = orbit_path(scenes.camera_pose(0), args.count, args.rate, args.orbit_speed,
                          args.bob)
    for index in tqdm(range(args.count), desc='synth', unit='img'):
        if path is None:
            sample = scenes.sample(index)
            writer.add(index, sample)
        else:
            moved = args.move is not None and index >= args.count // 2
            sample = scenes.sample_with_layout(0, path[index],
                                               dict([args.move]) if moved else None)[0]
            writer.add(index, sample, path[index])
        if index < args.previews:
            write_rgb_png(root / 'previews' / f'{index:06d}.png', draw_preview(sample))
    writer.finish()
    write_json(root / 'synth_info.json', {
        'seed': args.seed, 'count': args.count, 'scene_style': args.scene_style,
        'objects': targets,
        'distractor_objects': sorted(distractors), 'config': asdict(config),
        'camera_path': None if path is None else {
            'rate_hz': args.rate, 'orbit_deg_per_s': args.orbit_speed, 'bob_m': args.bob,
            'moved': None if args.move is None else {
                'object': args.move[0], 'dx_dy_m': list(args.move[1]),
                'from_frame': args.count // 2}}})
