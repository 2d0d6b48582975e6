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
What one parameter of ``bbpose_node`` is, and the checks of the node's own values.

A ``ParameterSpec`` is one row of the table in ``params.py``: default (and so type),
description, when the node reads it, range and check. The checks here raise InputError
saying what is wrong with a value of the right type; ``params.check_value`` names the
parameter.
"""

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
import os
from pathlib import Path
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

from bbpose_ros.core.data.bop import DEFAULT_DATASET
from bbpose_ros.core.util.errors import InputError

APPLIES = ('start', 'configure', 'pipeline', 'frame')


@dataclass(frozen=True)
class ParameterSpec:
    """
    One parameter of the node.

    Attributes:
        default: the declared default; its type is the parameter's (rclpy refuses others).
        description: one line for the descriptor (config/bbpose.yaml says more).
        applies: when the node reads it, one of APPLIES.
        value_range: (from, to), inclusive, for the descriptor and the check.
        check: raises InputError saying what is wrong with a value of the right type.
        option: whether it is a setting of PipelineOptions (checked by making one).

    """

    default: Any
    description: str
    applies: str
    value_range: tuple[float, float] | None = None
    check: Callable[[Any], None] | None = field(default=None, compare=False)
    option: bool = False

    @property
    def descriptor(self) -> ParameterDescriptor:
        """Return the ParameterDescriptor (read-only for ``start`` parameters)."""
        descriptor = ParameterDescriptor(description=self.description,
                                         read_only=self.applies == 'start')
        if self.value_range is not None and isinstance(self.default, int) \
                and not isinstance(self.default, bool):
            descriptor.integer_range = [IntegerRange(from_value=self.value_range[0],
                                                     to_value=self.value_range[1], step=1)]
        elif self.value_range is not None:
            descriptor.floating_point_range = [FloatingPointRange(
                from_value=float(self.value_range[0]), to_value=float(self.value_range[1]))]
        return descriptor


def one_of(choices: Sequence[str]) -> Callable[[str], None]:
    """Return the check that a value is one of ``choices``."""
    def check(value: str) -> None:
        if value not in choices:
            raise InputError(f'"{value}" is not one of {", ".join(choices)}')
    return check


def check_object_names(names: Sequence[str]) -> None:
    """Check a list of object names: at least one, none twice."""
    if not names:
        raise InputError('give at least one object name')
    repeated = sorted({name for name in names if names.count(name) > 1})
    if repeated:
        raise InputError(f'{", ".join(repeated)} listed more than once')


def check_weights_file(text: str) -> None:
    """Check a weights file path: empty (the shipped file) or an existing file."""
    if text and not Path(text).is_file():
        raise InputError(f'weights file not found: {text}')


def check_tf_prefix(prefix: str) -> None:
    """Check a TF frame prefix: tf2 refuses a leading slash, whitespace makes ids unusable."""
    if prefix.startswith('/') or any(c.isspace() for c in prefix):
        raise InputError(f'"{prefix}" starts with "/" or holds whitespace (tf2 frame ids '
                         f'may not)')


def dataset_path(text: str) -> Path:
    """Return the dataset folder ``text`` names; empty: $BBPOSE_DATASET, else the default."""
    return Path(text or os.environ.get('BBPOSE_DATASET') or DEFAULT_DATASET)


def check_dataset_dir(text: str) -> None:
    """Check that the dataset folder ``text`` resolves to has a models/ folder."""
    path = dataset_path(text)
    if not (path / 'models').is_dir():
        raise InputError(f'{path} has no models/ folder (BOP meshes and models_info.json)')
