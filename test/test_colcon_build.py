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

"""The package builds with colcon in a fresh workspace and its installed executable runs."""

import os
from pathlib import Path
import shutil
import subprocess
import sys

import pytest

pytestmark = pytest.mark.slow   # runs colcon in a process

ROOT = Path(__file__).parents[1]


def test_colcon_build_and_run(tmp_path):
    colcon = Path(sys.executable).with_name('colcon')
    source = tmp_path / 'src' / 'bbpose_ros'
    tracked = subprocess.run(['git', 'ls-files', '-co', '--exclude-standard'], cwd=ROOT,
                             capture_output=True, text=True, check=True).stdout.split()
    for name in tracked:
        if (ROOT / name).is_file():
            (source / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, source / name)
    build = subprocess.run([str(colcon), 'build', '--base-paths', 'src'], cwd=tmp_path,
                           capture_output=True, text=True, timeout=600)
    assert build.returncode == 0, build.stdout + build.stderr
    install = tmp_path / 'install' / 'bbpose_ros'
    assert (install / 'share' / 'bbpose_ros' / 'package.xml').is_file()
    assert (install / 'share' / 'ament_index' / 'resource_index' / 'packages'
            / 'bbpose_ros').is_file()
    assert (install / 'share' / 'bbpose_ros' / 'config').is_dir()
    site = next(install.glob('lib/python3*/site-packages'))
    env = {**os.environ, 'PYTHONPATH': str(site)}
    result = subprocess.run(
        [str(install / 'lib' / 'bbpose_ros' / 'bbpose'), '--version'],
        capture_output=True, text=True, env=env, cwd=tmp_path, timeout=120)
    assert result.returncode == 0, result.stderr
    assert 'bbpose 0.1.0' in result.stdout
    where = subprocess.run([sys.executable, '-c', 'import bbpose_ros; print(bbpose_ros.__file__)'],
                           capture_output=True, text=True, env=env, cwd=tmp_path, check=True)
    assert where.stdout.startswith(str(site))
