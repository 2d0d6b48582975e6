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
Under pytest-xdist (``make test`` runs ``-n 2``), each worker takes its own block of ROS
domains and its share of the CPU's threads (``pytest_configure``).
"""

import os
from pathlib import Path
import sys

import pytest

from bbpose_ros.core.data.bop import BopDataset

REPO_ROOT = Path(__file__).resolve().parents[1]
DATASET_FIXTURES = {'lmo_root', 'lmo', 'lmo_models', 'lmo_frames'}
# The ROS domains a worker may use: its ROS_DOMAIN_ID + the modules' offsets (0..15 in
# test_ros_support.use_private_domain); the next worker's block starts this far on.
DOMAINS_PER_WORKER = 16
# torch's intra-op threads of this process, when an xdist worker sets them (else None).
WORKER_THREADS = None


def pytest_configure(config):
    """
    Give an xdist worker its own ROS domains and its share of the CPU threads.

    Worker k moves the run's ROS_DOMAIN_ID (without one: 1 + the pid of the run's main
    process modulo 100, the same for all its workers) by k * DOMAINS_PER_WORKER, before any
    test module reads it, so no two workers ever share a domain. The cores are shared out
    between the workers (torch, OpenMP and the processes the tests start) so that they do not
    oversubscribe the CPU.
    """
    global WORKER_THREADS
    worker = os.environ.get('PYTEST_XDIST_WORKER')
    if not worker:
        return
    index = int(worker.removeprefix('gw'))
    base = int(os.environ.get('ROS_DOMAIN_ID') or 1 + os.getppid() % 100)
    os.environ['ROS_DOMAIN_ID'] = str(base + index * DOMAINS_PER_WORKER)
    workers = int(os.environ.get('PYTEST_XDIST_WORKER_COUNT', '1'))
    WORKER_THREADS = max(1, (os.cpu_count() or 1) // workers)
    os.environ['OMP_NUM_THREADS'] = str(WORKER_THREADS)
    import torch
    torch.set_num_threads(WORKER_THREADS)


@pytest.fixture(autouse=True)
def worker_threads():
    """Put torch's threads back to the worker's share after a test that changed them."""
    yield
    torch = sys.modules.get('torch')
    if WORKER_THREADS and torch is not None and torch.get_num_threads() != WORKER_THREADS:
        torch.set_num_threads(WORKER_THREADS)


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
