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
One way to declare a setting: a dataclass field that carries its declaration.

A settings class (``PipelineOptions``, the training runs' settings) declares each of its
fields with ``setting``: default, one-line description, inclusive range or choices.
``declared`` reads them back as ``Setting`` records, from which the node's parameter
descriptors, config/bbpose.yaml and the command-line options (``cli/settings_options.py``)
are generated; ``check_setting`` is the one check of a value, which a settings class runs
on each field when it is made (``check_settings``), wherever its values come from. A field
holding a settings object of its own (``nested``: it checks itself) is no setting, and a
subclass gives an inherited setting another default with ``redeclared``.

A leaf: it imports nothing but the errors, so the parameter table and the command-line
parsers load without torch or numba.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, fields
from functools import cache
from typing import Any

from bbpose_ros.core.util.errors import InputError


def setting(default: Any, description: str, *, low: float | None = None,
            high: float | None = None, choices: tuple[str, ...] | None = None,
            metavar: str | None = None,
            check: Callable[[Any], str | None] | None = None) -> Any:
    """
    Make a dataclass field of one setting.

    Args:
        default: the value taken when none is given.
        description: one line, with units.
        low: the inclusive lower bound (None: unbounded).
        high: the inclusive upper bound (None: unbounded).
        choices: the values a str setting takes.
        metavar: how a tuple value is spelled, e.g. 'W,H'.
        check: a further check of a value of the right type: its reason, or None to accept.

    """
    return field(default=default, metadata={
        'description': description, 'range': (low, high), 'choices': choices,
        'metavar': metavar, 'check': check})


def above_zero(value: float | tuple[float, ...]) -> str | None:
    """
    Return why a number (or a tuple's smallest) is refused: not > 0; None: accepted.

    A ``check`` for settings whose range is open at 0 (``low`` is inclusive).
    """
    smallest = min(value) if isinstance(value, tuple) else value
    return None if smallest > 0 else f'{smallest} is not > 0'


def redeclared(settings_class: type, name: str, default: Any) -> Any:
    """Make a subclass's field of ``settings_class``'s setting ``name``, another default."""
    return field(default=default, metadata=settings_class.__dataclass_fields__[name].metadata)


def nested(factory: Callable[[], Any]) -> Any:
    """Make a dataclass field of a settings object (made by ``factory``): no setting itself."""
    return field(default_factory=factory, metadata={'nested': True})


@dataclass(frozen=True)
class Setting:
    """
    One declared setting as the generators see it.

    Attributes:
        name: the field's name, also the node parameter's and (dashed) the CLI option's.
        kind: the Python type of its values: bool, int, float, str or tuple.
        default: the class's value.
        description: one line, with units.
        limits: inclusive (low, high), either None where unbounded; None: neither bound.
        choices: the values a str setting takes, or None.
        optional: whether None is a value (it means what the description says).
        metavar: how a tuple value is spelled, or None.
        check: a further check of a value (its reason, or None), or None.
        items: a tuple's type of items (int or float), or None.
        length: a tuple's number of items; None: one or more.

    """

    name: str
    kind: type
    default: Any
    description: str
    limits: tuple[float | None, float | None] | None
    choices: tuple[str, ...] | None
    optional: bool = False
    metavar: str | None = None
    check: Callable[[Any], str | None] | None = None
    items: type | None = None
    length: int | None = None


_TYPES = {'bool': bool, 'int': int, 'float': float, 'str': str}
# {spelling: (type of items, number of items or None: one or more)} of the tuple settings.
_TUPLES = {'tuple[int, int]': (int, 2), 'tuple[int, ...]': (int, None),
           'tuple[float, ...]': (float, None)}


def declared(settings_class: Any) -> dict[str, Setting]:
    """
    Return {name: Setting} of a settings class (or object), in declaration order.

    Fields of nested settings objects (``nested``) are left out.
    """
    return _declared(settings_class if isinstance(settings_class, type) else
                     type(settings_class))


@cache
def _declared(settings_class: type) -> dict[str, Setting]:
    result = {}
    for declaration in fields(settings_class):
        if declaration.metadata.get('nested'):
            continue
        spelled = declaration.type if isinstance(declaration.type, str) else \
            declaration.type.__name__
        kind, _, none = spelled.partition(' | ')
        metadata = declaration.metadata
        low, high = metadata['range']
        items, length = _TUPLES.get(kind, (None, None))
        result[declaration.name] = Setting(
            declaration.name, tuple if items else _TYPES[kind], declaration.default,
            metadata['description'], None if low is None and high is None else (low, high),
            metadata['choices'], none == 'None', metadata['metavar'], metadata['check'],
            items, length)
    return result


def check_settings(settings: Any) -> None:
    """Check each declared field of a settings object in order (``check_setting``)."""
    for name, declaration in declared(settings).items():
        check_setting(declaration, getattr(settings, name))


def check_setting(declaration: Setting, value: Any) -> None:
    """Raise InputError 'name: reason' when ``value`` is not one ``declaration`` takes."""
    name, expected = declaration.name, declaration.kind
    if value is None and declaration.optional:
        return
    if expected is tuple:
        parts = tuple(value) if isinstance(value, (tuple, list)) else ()
        accepted = (len(parts) == declaration.length if declaration.length else
                    len(parts) > 0) and all(
            isinstance(part, (int, declaration.items)) and not isinstance(part, bool)
            for part in parts)
        values = parts
    else:
        # bool is an int in Python; an int is a fine float; neither is accepted the other way.
        accepted = isinstance(value, expected) and not (
            expected is not bool and isinstance(value, bool))
        if expected is float:
            accepted = isinstance(value, (int, float)) and not isinstance(value, bool)
        values = (value,)
    if not accepted and expected is tuple:
        count = declaration.length or 'one or more'
        items = 'integers' if declaration.items is int else 'numbers'
        raise InputError(f'{name}: {value!r} is not {count} {items} ({declaration.metavar})')
    if not accepted:
        raise InputError(f'{name}: {value!r} is not of type {expected.__name__}')
    low, high = declaration.limits or (None, None)
    for part in values:      # written so that NaN is out of every range
        if (low is not None and not part >= low) or (high is not None and not part <= high):
            shown = f'[{low}, {high}]' if low is not None and high is not None else \
                f'(>= {low})' if high is None else f'(<= {high})'
            raise InputError(f'{name}: {part} is out of range {shown}')
    if declaration.choices is not None and value not in declaration.choices:
        raise InputError(f'{name}: "{value}" is not one of {", ".join(declaration.choices)}')
    reason = None if declaration.check is None else declaration.check(value)
    if reason is not None:
        raise InputError(f'{name}: {reason}')
