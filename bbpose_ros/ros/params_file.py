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
A node's parameters file: read as rclpy reads it, written by the package's one writer.

For the tools that start or imitate the node (``bbpose bench``, ``replay-eval``,
``adapt``, ``eval --params``): the values a ``bbpose_node`` would get from a file. Every
parameters file the package writes (config/bbpose.yaml, ``bbpose add-object``'s and
``bbpose adapt``'s params.yaml) comes from ``params_file_text``; the tools hand over what
they made as a ``PipelineFiles``, and ``pipeline_values`` names the node's parameters.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path
import re
from typing import Any

from ament_index_python.packages import get_package_share_directory
import yaml

from bbpose_ros.core.pipeline.loader import PipelineFiles
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.core.util.files import atomic_output
from bbpose_ros.ros.params import NODE_NAME, PARAMETERS

INDENT = '    '


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


def yaml_value(value: Any) -> str:
    """Return ``value`` (bool, int, float, str or a list of them) as YAML reads it back."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, int):
        return repr(value)
    if isinstance(value, float):
        text = repr(value)          # '1e-05', 'inf' and 'nan' would read back as strings
        return text if yaml.safe_load(text) == value else yaml.safe_dump(value).split('\n')[0]
    if isinstance(value, str):
        if re.fullmatch(r'[A-Za-z_][A-Za-z0-9_.+-]*', value) and \
                yaml.safe_load(value) == value:
            return value
        return "'" + value.replace("'", "''") + "'"
    if isinstance(value, (list, tuple)):
        return '[' + ', '.join(yaml_value(item) for item in value) + ']'
    raise TypeError(f'no YAML form for {value!r}')


def params_file_text(values: Mapping[str, Any], header: str,
                     comments: Mapping[str, str] | None = None) -> str:
    """
    Return a parameters file setting ``values`` ({name: value}) for every node (``/**``).

    ``header`` (comment lines, each ending in a newline) comes first. A parameter with an
    entry in ``comments`` (comment lines, without the last newline) gets it above its line,
    and a blank line before the next parameter.
    """
    comments = comments or {}
    blocks = [(f'{comments[name]}\n' if name in comments else '') +
              f'{INDENT}{name}: {yaml_value(value)}\n' for name, value in values.items()]
    return header + '/**:\n  ros__parameters:\n' + ('\n' if comments else '').join(blocks)


def write_params_file(path: Path | str, values: Mapping[str, Any], header: str) -> None:
    """Write ``params_file_text(values, header)`` to ``path``, atomically."""
    with atomic_output(Path(path)) as tmp:
        tmp.write_text(params_file_text(values, header))


def pipeline_values(files: PipelineFiles) -> dict[str, Any]:
    """
    Return {name: value} of the node's parameters that load ``files``.

    ``objects``, then ``dataset_dir`` and the ``<network>_weights`` files (absolute paths)
    where ``files`` gives them.
    """
    values: dict[str, Any] = {'objects': list(files.objects)}
    if files.dataset_dir is not None:
        values['dataset_dir'] = str(Path(files.dataset_dir).resolve())
    for kind in ('detector', 'qnet', 'dense'):
        path = getattr(files.weights, kind)
        if path is not None:
            values[f'{kind}_weights'] = str(Path(path).resolve())
    return values
