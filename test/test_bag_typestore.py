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

"""The bag tools' typestore finds the packages rosbags lacks without the Makefile's env."""

from pathlib import Path
import sys

import pytest

from bbpose_ros.bags import typestore
from bbpose_ros.core.util.errors import InputError

DETECTIONS = 'vision_msgs/msg/Detection3DArray'


def test_the_typestore_finds_vision_msgs_without_ament_prefix_path(monkeypatch):
    monkeypatch.delenv('AMENT_PREFIX_PATH', raising=False)
    typestore.add_missing_types({DETECTIONS, 'sensor_msgs/msg/Image'})
    assert DETECTIONS in typestore.TYPESTORE.types
    assert typestore.share_directory('vision_msgs') == Path(sys.prefix) / 'share' / 'vision_msgs'


def test_the_ament_prefix_path_comes_first(monkeypatch, tmp_path):
    (tmp_path / 'share' / 'ament_index' / 'resource_index' / 'packages').mkdir(parents=True)
    (tmp_path / 'share' / 'ament_index' / 'resource_index' / 'packages' / 'vision_msgs').touch()
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(tmp_path))
    assert typestore.share_directory('vision_msgs') == tmp_path / 'share' / 'vision_msgs'


def test_a_package_found_nowhere_is_named(monkeypatch, tmp_path):
    monkeypatch.delenv('AMENT_PREFIX_PATH', raising=False)
    monkeypatch.setattr(typestore.sys, 'prefix', str(tmp_path))
    with pytest.raises(InputError, match=f'ROS package vision_msgs not found: no '
                                         f'share/vision_msgs in {tmp_path} '):
        typestore.share_directory('vision_msgs')
