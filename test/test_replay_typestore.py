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

"""``bbpose replay-eval`` writes its results bag without the Makefile's environment."""

from pathlib import Path
import sys

import pytest

from bbpose_ros.cli.graph import replay
from bbpose_ros.core.errors import InputError

DETECTIONS = 'vision_msgs/msg/Detection3DArray'


def test_the_typestore_finds_vision_msgs_without_ament_prefix_path(monkeypatch):
    monkeypatch.delenv('AMENT_PREFIX_PATH', raising=False)
    typestore = replay.typestore_of({DETECTIONS, 'sensor_msgs/msg/Image'})
    assert DETECTIONS in typestore.types
    assert replay.share_directory('vision_msgs') == Path(sys.prefix) / 'share' / 'vision_msgs'


def test_a_package_found_nowhere_is_named(monkeypatch, tmp_path):
    monkeypatch.delenv('AMENT_PREFIX_PATH', raising=False)
    monkeypatch.setattr(replay.sys, 'prefix', str(tmp_path))
    with pytest.raises(InputError, match=f'ROS package vision_msgs not found: '
                                         f'AMENT_PREFIX_PATH is not set and {tmp_path} has '
                                         'no share/vision_msgs'):
        replay.typestore_of({DETECTIONS})
