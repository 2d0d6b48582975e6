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
Command-line options generated from declared settings (``core/util/declarations.py``).

Each setting ``name`` becomes ``--name-with-dashes`` with its type, choices and description
(a bool: ``--name`` / ``--no-name``; a tuple: ``W,H``), defaulting to None: an option not
given leaves its setting to whatever else supplies it (the settings class's default, a
parameters file). ``bbpose eval`` and ``bbpose bench`` take the pipeline's settings this
way (``PipelineOptions``: the node's parameters of the same names), ``bbpose train`` each
stage's training settings; ``settings_made`` makes the settings object of the options
given and names the option of a value it refuses.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterable, Mapping
from typing import Any, TypeVar

from bbpose_ros.core.util.declarations import declared
from bbpose_ros.core.util.errors import InputError

Settings = TypeVar('Settings')

PIPELINE_TITLE = 'pipeline settings (node parameters of the same name)'
TRAINING_TITLE = 'training settings (recorded in the weight file)'


def add_settings_options(parser: argparse.ArgumentParser, settings_class: type, title: str,
                         *, names: Iterable[str] | None = None,
                         show_defaults: bool = False) -> None:
    """
    Add one option per setting of ``settings_class`` (of ``names``), in a group ``title``.

    Each defaults to None (not given); with ``show_defaults`` the help names the setting's
    default in the class, as the option spells it.
    """
    group = parser.add_argument_group(title)
    settings = declared(settings_class)
    for setting in (settings.values() if names is None else map(settings.get, names)):
        text = setting.description
        if show_defaults:
            text += f' (default {spelled(setting.default)})'
        flag, text = f'--{setting.name.replace("_", "-")}', text.replace('%', '%%')
        if setting.kind is bool:
            group.add_argument(flag, dest=setting.name, default=None,
                               action=argparse.BooleanOptionalAction, help=text)
        elif setting.kind is tuple:
            group.add_argument(flag, dest=setting.name, default=None, type=int_tuple,
                               metavar=setting.metavar, help=text)
        else:
            group.add_argument(flag, dest=setting.name, default=None, type=setting.kind,
                               choices=setting.choices, help=text)


def settings_given(args: argparse.Namespace, names: Iterable[str]) -> dict[str, Any]:
    """Return {name: value} of the settings options of ``names`` that are set (not None)."""
    return {name: getattr(args, name) for name in names
            if getattr(args, name, None) is not None}


def settings_made(settings_class: type[Settings], args: argparse.Namespace,
                  base: Mapping[str, Any] | None = None, **given: Any) -> Settings:
    """
    Return the ``settings_class`` of its options given, over ``base``, under ``given``.

    ``base`` ({name: value}, e.g. a node parameters file's) fills the settings not given as
    options, ``given`` ({name: value}) overrides them; the rest keep the class's defaults.
    Raises InputError '--option-name: reason' (or '--name / --name: reason') for a value or
    combination it does not take.
    """
    values = {**(base or {}), **settings_given(args, declared(settings_class)), **given}
    try:
        return settings_class(**values)
    except InputError as err:      # 'name: reason' or 'name / name: reason'
        head, _, reason = str(err).partition(': ')
        options = ' / '.join(f'--{n.replace("_", "-")}' for n in head.split(' / '))
        raise InputError(f'{options}: {reason}') from err


def spelled(value: Any) -> str:
    """Spell a setting's value as its option takes it: 0.001, true, 192,160, none."""
    if value is None or isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, tuple):
        return ','.join(map(str, value))
    return f'{value:g}' if isinstance(value, float) else str(value)


def int_tuple(text: str) -> tuple[int, ...]:
    """Parse '1,2,3' into a tuple of integers (an argparse type)."""
    try:
        return tuple(int(x) for x in text.split(','))
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected comma-separated integers, got {text!r}')
