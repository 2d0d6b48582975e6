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
A node's parameters file read as rclpy reads it, and the package's own config files.

For the tools that start or imitate the node (``bbpose bench``, ``replay-eval``,
``adapt``, ``eval --params``): the values a ``bbpose_node`` would get from a file.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

from ament_index_python.packages import get_package_share_directory
import yaml

from bbpose_ros.core.util.errors import InputError
from bbpose_ros.ros.params import NODE_NAME, PARAMETERS


def read_params_file(path: Path | str, overrides: Iterable[str] = (),
                     node_name: str = NODE_NAME) -> dict[str, Any]:
    """
    Read the parameter values a node gets from a ROS 2 parameters file, as rclpy does.

    The ``/**`` block applies first, then the node's own block; ``overrides`` are
    ``name:=value`` strings (YAML values, as ``-p`` takes them) applied last. Parameters
    left unset get their declared default.
    """
    path = Path(path)
    try:
        content = yaml.safe_load(path.read_text()) or {}
    except FileNotFoundError as err:
        raise InputError(f'parameters file not found: {path}') from err
    except yaml.YAMLError as err:
        raise InputError(f'parameters file {path} is not valid YAML: {err}') from err
    values = {name: spec.default for name, spec in PARAMETERS.items()}
    for block in ('/**', node_name, f'/{node_name}'):
        values.update((content.get(block) or {}).get('ros__parameters') or {})
    for override in overrides:
        name, separator, text = override.partition(':=')
        if not separator:
            raise InputError(f'parameter override "{override}" is not name:=value')
        values[name] = yaml.safe_load(text)
    return values


def package_config_file(name: str) -> Path:
    """Return config/<name> of the source tree, else of the installed share/bbpose_ros."""
    source = Path(__file__).resolve().parents[2] / 'config' / name
    if source.is_file():
        return source
    try:
        return Path(get_package_share_directory('bbpose_ros')) / 'config' / name
    except (LookupError, OSError):   # not installed, or AMENT_PREFIX_PATH unset
        return source
