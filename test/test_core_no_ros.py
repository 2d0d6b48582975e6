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

"""The core runs without ROS: importing all of it loads no rclpy and no message package."""

from pathlib import Path
import subprocess
import sys

import pytest

pytestmark = pytest.mark.slow   # imports the core in a fresh Python process

CORE = Path(__file__).parents[1] / 'bbpose_ros' / 'core'


def test_core_imports_no_ros():
    modules = sorted('.'.join(p.relative_to(CORE.parents[1]).with_suffix('').parts)
                     .removesuffix('.__init__') for p in CORE.rglob('*.py'))
    code = ('import importlib, sys\n'
            f'for name in {modules!r}:\n'
            '    importlib.import_module(name)\n'
            'ros = [m for m in sys.modules if m.split(".")[0] in ("rclpy", "rosidl_runtime_py")\n'
            '       or m.split(".")[0].endswith("_msgs")]\n'
            'print(len(sys.modules)); assert not ros, ros\n')
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                            cwd=CORE.parents[1], timeout=120)
    assert result.returncode == 0, result.stderr
    assert len(modules) >= 60
