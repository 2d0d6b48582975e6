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

"""The networks' configurations to and from the JSON ``architecture`` of their weight files."""

from collections.abc import Mapping
from dataclasses import asdict, fields
from typing import Any, get_origin, Self


class ConfigDict:
    """
    Mixin of a frozen config dataclass: ``to_dict`` for the weight file, ``from_dict`` back.

    JSON has no tuples: tuple fields are written as lists and read back as tuples. Fields
    missing from the dict (files written before the field existed) take their defaults.
    """

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (tuples become lists)."""
        return {name: list(value) if isinstance(value, tuple) else value
                for name, value in asdict(self).items()}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Self:
        """Inverse of ``to_dict``."""
        tuples = {field.name for field in fields(cls) if get_origin(field.type) is tuple}
        return cls(**{name: tuple(value) if name in tuples else value
                      for name, value in data.items()})
