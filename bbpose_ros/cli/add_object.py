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
``bbpose add-object``: a new object from its mesh to weight files the node loads.

The mesh is checked as ``bbpose check-mesh`` checks it; the shipped networks (or those of
``--base-weights``) get one more object, trained on table-top renders with everything they
already know frozen (``core.add_object``). ``bbpose remove-object`` drops an
object's rows instead: the base of a leave-one-out measurement.
"""

import argparse
import os
from pathlib import Path
from typing import TYPE_CHECKING

from bbpose_ros.cli.common import add_dataset_argument, add_mesh_arguments
from bbpose_ros.cli.settings_options import add_settings_options, settings_made
from bbpose_ros.core.add_object.add_object_settings import AddObjectSettings
from bbpose_ros.core.util.errors import InputError

if TYPE_CHECKING:
    from bbpose_ros.core.pipeline.loader import PipelineFiles

NETWORK_FILES = {'detector': 'detector.pt', 'qnet': 'qnet.pt', 'dense': 'dense.pt'}
PARAMS_HEADER = ('# bbpose_node parameters written by bbpose add-object; the others keep their\n'
                 '# defaults (config/bbpose.yaml documents every parameter).\n')


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``bbpose add-object`` and ``bbpose remove-object``."""
    from bbpose_ros.core.inference.weights import WEIGHTS_DIR
    add = subparsers.add_parser(
        'add-object', help='teach the networks a new object from its mesh (minutes on a CPU)',
        description='Check a mesh, render table-top scenes of it among the known objects, '
                    'and extend the detector, Q-Net and the dense net by one object (only its '
                    'new output rows learn; what the networks know stays as it is). Writes '
                    'to --out: the weight files and int8 graphs, dataset/ (meshes for the '
                    'node), params.yaml (start the node with it), preview.png and '
                    'report.json. Rerun the same command to resume.')
    add_mesh_arguments(add)
    add.add_argument('--name', required=True,
                     help='the object name: topics ~/<name>/pose, the objects parameter')
    add.add_argument('--out', required=True, type=Path, help='output folder (resumable)')
    add.add_argument('--symmetry', default=None, metavar='AXIS:FOLD',
                     help='a discrete symmetry, e.g. z:2 (the same after half a turn about '
                          "the model's z axis through its box centre; default none)")
    add_dataset_argument(add)
    add.add_argument('--base-weights', type=Path, default=WEIGHTS_DIR,
                     help='folder of the detector.pt, qnet.pt and dense.pt to extend, whose '
                          'objects have meshes in --dataset (default: the shipped ones)')
    add.add_argument('--backgrounds', type=Path, nargs='+', default=None, metavar='DIR',
                     help='folders of photographs for the backgrounds of the renders (`make '
                          'photos`; default: procedural textures only)')
    add_settings_options(add, AddObjectSettings, 'renders and training (recorded in report.json)',
                         names=('scenes', 'crops', 'seed', 'workers'), show_defaults=True)
    add.add_argument('--keep-renders', action='store_true',
                     help='keep renders/ (the training renders, hundreds of MB) when done')
    add.add_argument('--threads', type=int, default=None,
                     help='torch threads (default: all cores)')
    add.set_defaults(func=run)

    remove = subparsers.add_parser(
        'remove-object', help="drop an object's rows from the three networks",
        description='Write detector.pt, qnet.pt and dense.pt without one object: the other '
                    "objects' outputs unchanged (the base of a leave-one-out test of "
                    '`bbpose add-object`).')
    remove.add_argument('--name', required=True, help='the object to drop')
    remove.add_argument('--base-weights', type=Path, default=WEIGHTS_DIR,
                        help='folder of the three weight files (default: the shipped ones)')
    remove.add_argument('--out', required=True, type=Path,
                        help='folder for the three files (must not hold them yet)')
    remove.set_defaults(func=run_remove)


def base_weight_files(folder: Path) -> dict[str, Path]:
    """{kind: path} of the three weight files in ``folder``; InputError if one is missing."""
    files = {kind: Path(folder) / name for kind, name in NETWORK_FILES.items()}
    missing = [str(path) for path in files.values() if not path.is_file()]
    if missing:
        raise InputError(f'weight file(s) not found: {", ".join(missing)}')
    return files


def write_params(out: Path, files: 'PipelineFiles') -> Path:
    """Write ``out``/params.yaml, the node's parameters that load ``files``; return its path."""
    from bbpose_ros.ros.params_file import pipeline_values, write_params_file
    path = Path(out) / 'params.yaml'
    write_params_file(path, pipeline_values(files), PARAMS_HEADER)
    return path


def run(args: argparse.Namespace) -> int:
    """Run ``bbpose add-object``; returns the exit status."""
    import json
    import sys

    import numpy as np
    import torch

    from bbpose_ros.core.data.mesh_check import check_mesh
    from bbpose_ros.core.data.models import check_names
    from bbpose_ros.core.synth.backgrounds import PhotoBackgrounds
    from bbpose_ros.core.add_object.add_object_settings import AddedObject, axis_symmetries
    from bbpose_ros.core.add_object.add_object_stages import AddObject
    check_names({1: args.name}, '--name')
    if args.threads:
        torch.set_num_threads(args.threads)
    mesh = check_mesh(args.mesh, args.units, args.color, args.max_faces)
    for note in mesh.notes:
        print(f'note: {note}')
    symmetries = np.zeros((0, 4, 4))
    if args.symmetry:
        axis, _, fold = args.symmetry.partition(':')
        if not fold.isdigit():
            raise InputError(f'--symmetry is AXIS:FOLD, e.g. z:2, got {args.symmetry!r}')
        symmetries = axis_symmetries(mesh, axis, int(fold))
    settings = settings_made(AddObjectSettings, args)
    backgrounds = PhotoBackgrounds.from_folders(args.backgrounds) if args.backgrounds else None
    task = AddObject(AddedObject(args.name, mesh, symmetries),
                     base_weight_files(args.base_weights), args.dataset, args.out, settings,
                     backgrounds, command=' '.join(sys.argv), keep_renders=args.keep_renders)
    report = task.run()
    params = write_params(args.out, task.pipeline_files())
    print(f'\n{args.name} added in {report["seconds"]["total"] / 60:.1f} min '
          f'({os.cpu_count()} CPU cores, peak memory {report["peak_rss_mb"] / 1024:.1f} GB, '
          f'{report["disk_mb"]:.0f} MB in {args.out}); on held-out renders:')
    for kind, figures in report.get('held_out_renders', {}).items():
        print(f'  {kind:9s}' + json.dumps({k: round(v, 3) for k, v in figures.items()}))
    print(f'preview: {args.out / "preview.png"}\nnode: .venv/bin/bbpose_node --ros-args '
          f'--params-file {params}\n  (with colcon: ros2 run bbpose_ros bbpose_node '
          f'--ros-args --params-file {params})')
    return 0


def run_remove(args: argparse.Namespace) -> int:
    """Run ``bbpose remove-object``; returns the exit status."""
    from bbpose_ros.core.inference.weights import load_network, save_weights
    from bbpose_ros.core.training.object_rows import with_objects
    files = base_weight_files(args.base_weights)
    for kind, path in files.items():
        target = args.out / NETWORK_FILES[kind]
        if target.exists():
            raise InputError(f'{target} exists already; choose a new --out')
        network = load_network(path, kind)
        objects = [name for name in network.config.objects if name != args.name]
        if len(objects) == len(network.config.objects):
            raise InputError(f'{path} has no object named {args.name!r} '
                             f'(objects: {", ".join(network.config.objects)})')
        record = dict(network.metadata.get('training', {}), removed=args.name)
        args.out.mkdir(parents=True, exist_ok=True)
        save_weights(target, with_objects(network, objects), kind, record)
    print(f'wrote {", ".join(NETWORK_FILES.values())} without {args.name} to {args.out}')
    return 0
