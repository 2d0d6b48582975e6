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
``bbpose check-mesh``: check a new object's mesh; optionally write it as a BOP model.

Problems (units, size, colours) are one error line naming the file and exit code 2; notes
(decimation, open edges) are printed. With ``--out`` the checked mesh becomes a BOP
``models/`` folder of one object (see ``bbpose_ros.core.data.mesh_check``).
"""

import argparse
from pathlib import Path

from bbpose_ros.cli.common import add_mesh_arguments
from bbpose_ros.core.data.mesh_check import check_mesh, write_bop_model
from bbpose_ros.core.util.errors import InputError


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the ``check-mesh`` subcommand on an argparse subparsers object; return it."""
    parser = subparsers.add_parser(
        'check-mesh', help="check a new object's mesh (units, size, colours, holes, faces)",
        description="Check a new object's mesh: units against its size, a tabletop size, "
                    'vertex colours (or a uniform --color), watertightness and face count '
                    '(a huge mesh is decimated). With --out, write it as a BOP models/ '
                    'folder: the PLY in mm with colours, its models_info.json entry '
                    '(diameter and box) and the names table models_names.json.')
    add_mesh_arguments(parser)
    parser.add_argument('--out', type=Path, default=None,
                        help='write a BOP models/ folder of the object here (must not exist)')
    parser.add_argument('--obj-id', type=int, default=1,
                        help='with --out: its BOP object id (default %(default)s)')
    parser.add_argument('--name', default=None,
                        help="with --out: the object's name, e.g. toy (default: the file's "
                             'stem)')
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Run ``bbpose check-mesh``; returns the exit status, a refused mesh raises InputError."""
    if args.out is None and (args.name is not None or args.obj_id != 1):
        raise InputError('--name and --obj-id name the object written by --out')
    checked = check_mesh(args.mesh, args.units, args.color, args.max_faces)
    extent = checked.vertices.max(axis=0) - checked.vertices.min(axis=0)
    print(f'{checked.path}: {len(checked.vertices)} vertices, {len(checked.faces)} faces, '
          f'diameter {checked.diameter_m:.4f} m, box {" x ".join(f"{x:.4f}" for x in extent)} '
          f'm, {"watertight" if not checked.open_edges else "open"}')
    for note in checked.notes:
        print(f'note: {note}')
    if args.out is not None:
        write_bop_model(checked, args.out, args.obj_id, args.name or Path(args.mesh).stem)
        print(f'wrote {args.out}: obj_{args.obj_id:06d}.ply (mm), models_info.json, '
              'models_names.json (add symmetries_discrete by hand for a symmetric object)')
    return 0
