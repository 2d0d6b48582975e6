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
Command-line options generated from the pipeline's settings (``options.SETTINGS``).

Each setting ``name`` becomes ``--name-with-dashes`` with its type, choices and
description (a bool: ``--name`` / ``--no-name``), so ``bbpose eval`` and ``bbpose bench``
take the same names, defaults and checks as the node's parameters.
"""

import argparse
from collections.abc import Collection, Mapping
from typing import Any

from bbpose_ros.core.inference.options import PipelineOptions, SETTINGS
from bbpose_ros.core.util.errors import InputError


def add_settings_arguments(parser: argparse.ArgumentParser, names: Collection[str],
                           defaults: Mapping[str, Any] | None = None) -> None:
    """
    Add one option per setting of ``names``.

    ``defaults`` gives each option's default ({name: value}); None: the settings' own
    (shown in the help). An option left at None is not set (``settings_of``).
    """
    group = parser.add_argument_group('pipeline settings (node parameters of the same name)')
    for name in names:
        setting = SETTINGS[name]
        default = setting.default if defaults is None else defaults.get(name)
        shown = ' (default %(default)s)' if defaults is None else ''
        text = setting.description + shown
        if setting.kind is bool:
            group.add_argument(f'--{name.replace("_", "-")}', dest=name, default=default,
                               action=argparse.BooleanOptionalAction, help=text)
        else:
            group.add_argument(f'--{name.replace("_", "-")}', dest=name, default=default,
                               type=setting.kind, choices=setting.choices, help=text)


def settings_of(args: argparse.Namespace, names: Collection[str]) -> dict[str, Any]:
    """Return {name: value} of the settings options of ``names`` that are set (not None)."""
    return {name: getattr(args, name) for name in names if getattr(args, name) is not None}


def options_of(args: argparse.Namespace, names: Collection[str],
               base: Mapping[str, Any] | None = None) -> PipelineOptions:
    """
    Return the PipelineOptions of the settings options of ``names`` set, over ``base``.

    ``base`` ({name: value}, e.g. a node parameters file's) fills the settings not given;
    the rest keep their defaults. Raises InputError '--option-name: reason' for a value or
    combination it does not take.
    """
    try:
        return PipelineOptions(**{**(base or {}), **settings_of(args, names)})
    except InputError as err:      # 'name: reason' or 'name / name: reason'
        head, _, reason = str(err).partition(': ')
        options = ' / '.join(f'--{n.replace("_", "-")}' for n in head.split(' / '))
        raise InputError(f'{options}: {reason}') from err
