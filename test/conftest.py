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
Shared fixtures: the real LM-O frames in ../shared (or $BBPOSE_DATASET), headless GL.

Every test that uses the LM-O fixtures is marked ``dataset`` (pytest.ini's markers).
"""

import os
from pathlib import Path

import pytest

from bbpose_ros.core.data.bop import BopDataset

REPO_ROOT = Path(__file__).resolve().parents[1]
DATASET_FIXTURES = {'lmo_root', 'lmo', 'lmo_models', 'lmo_frames'}


def dataset_path():
    """Return the LM-O dataset folder the tests read (never copied into the repo)."""
    return Path(os.environ.get('BBPOSE_DATASET', REPO_ROOT.parent / 'shared/datasets/lmo'))


def pytest_collection_modifyitems(items):
    """Mark ``dataset`` the tests that read LM-O through its fixtures (at any depth)."""
    for item in items:
        if DATASET_FIXTURES & set(getattr(item, 'fixturenames', ())):
            item.add_marker(pytest.mark.dataset)


@pytest.fixture(scope='session')
def lmo_root():
    """Path of the LM-O dataset; fails loudly when it is missing."""
    path = dataset_path().resolve()
    if not (path / 'models' / 'models_info.json').is_file():
        pytest.fail(f'LM-O dataset not found at {path}; set BBPOSE_DATASET')
    return path


@pytest.fixture(scope='session')
def lmo(lmo_root):
    """Open the LM-O BopDataset."""
    return BopDataset(lmo_root)


@pytest.fixture(scope='session')
def lmo_models(lmo):
    """All 8 LM-O object models, {name: ObjectModel}, metres."""
    return lmo.load_models()


@pytest.fixture(scope='session')
def lmo_frames(lmo):
    """All frames of the LM-O subset."""
    return lmo.frames()


@pytest.fixture(scope='session')
def egl():
    """Skip the tests that render when headless OpenGL (EGL) is unavailable: one render tells."""
    from bbpose_ros.core.geometry.camera import CameraIntrinsics
    from bbpose_ros.core.render import Lighting, MeshRenderer
    try:
        renderer = MeshRenderer(CameraIntrinsics(50.0, 50.0, 15.5, 11.5, 32, 24), {})
        renderer.render([], Lighting())
        renderer.close()
    except RuntimeError as err:
        pytest.skip(f'headless OpenGL (EGL) unavailable: {err}')
