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

"""The ament linters (flake8, pep257) and the copyright header, as tests."""

from pathlib import Path

from ament_flake8.main import main_with_errors as flake8_main
from ament_pep257.main import main as pep257_main
import pytest

ROOT = Path(__file__).parents[1]
FLAKE8 = ['--config', str(ROOT / 'test' / 'flake8.ini')]
SOURCES = ['bbpose_ros', 'test', 'setup.py', 'launch']
HEADER = ROOT.joinpath('setup.py').read_text().split('\n\n')[0]


@pytest.mark.linter
def test_flake8():
    paths = [str(ROOT / p) for p in SOURCES if (ROOT / p).exists()]
    rc, errors = flake8_main(argv=[*FLAKE8, *paths])
    assert rc == 0, f'{len(errors)} flake8 errors:\n' + '\n'.join(errors)


@pytest.mark.linter
def test_pep257():
    paths = [str(ROOT / p) for p in SOURCES if (ROOT / p).exists()]
    # The ament convention, with Google-style 'Args:' / 'Returns:' sections allowed.
    rc = pep257_main(argv=['--add-ignore', 'D406', 'D407', '--', *paths])
    assert rc == 0, 'pep257 errors, see the output above'


@pytest.mark.linter
def test_copyright_header():
    files = [p for s in SOURCES for p in ([ROOT / s] if s.endswith('.py') else
                                          sorted((ROOT / s).rglob('*.py')))]
    assert len(files) > 10
    missing = [str(p.relative_to(ROOT)) for p in files
               if p.stat().st_size and not p.read_text().startswith(HEADER)]
    assert not missing, f'missing the Apache-2.0 header: {missing}'
