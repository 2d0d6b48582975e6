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
The one ``rosbags`` typestore of the bag tools: ROS 2 Jazzy's messages, plus those it lacks.

rosbags knows no vision_msgs: ``add_missing_types`` reads a missing package's message
definitions from its installed share/<package>/msg/*.msg, found in the ament index without
ROS (``share_directory``).
"""

from collections.abc import Iterable
import os
from pathlib import Path
import sys

from rosbags.typesys import get_types_from_msg, get_typestore, Stores

from bbpose_ros.core.util.errors import InputError

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)


def add_missing_types(msgtypes: Iterable[str]) -> None:
    """Register in TYPESTORE every package of ``msgtypes`` (e.g. 'pkg/msg/Name') it lacks."""
    missing = {name.split('/')[0] for name in msgtypes if name not in TYPESTORE.types}
    definitions = {}
    for package in sorted(missing):
        for path in sorted((share_directory(package) / 'msg').glob('*.msg')):
            definitions.update(get_types_from_msg(path.read_text(),
                                                  f'{package}/msg/{path.stem}'))
    TYPESTORE.register(definitions)


def share_directory(package: str) -> Path:
    """
    Return an installed package's share/<package> folder.

    It is looked up in the ament index of each prefix of $AMENT_PREFIX_PATH (a sourced ROS
    install, or the Makefile's venv), then in the prefix this Python runs from
    (``sys.prefix``: the venv's own install), so no tool needs the Makefile's environment.
    """
    prefixes = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    prefixes.append(sys.prefix)
    for prefix in map(Path, prefixes):
        index = prefix / 'share' / 'ament_index' / 'resource_index' / 'packages'
        if (index / package).is_file():
            return prefix / 'share' / package
    raise InputError(f'ROS package {package} not found: no share/{package} in '
                     f'{", ".join(prefixes)} ($AMENT_PREFIX_PATH, then sys.prefix); '
                     'source a ROS install')
