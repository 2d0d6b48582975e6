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
Viewpoint models built once per mesh and kept in a cache folder.

A model is a function of the mesh and the build settings only, so its file is named after
a digest of both: a changed mesh gets a new file, never a stale one.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
import os
from pathlib import Path
from typing import TYPE_CHECKING

from tqdm import tqdm

from bbpose_ros.core.refine.viewpoint_model import (build_viewpoint_model, mesh_digest,
                                                    ViewpointModel)
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.core.util.files import atomic_output

if TYPE_CHECKING:
    from bbpose_ros.core.data.models import ObjectModel

DEFAULT_SUBDIVISIONS = 2
DEFAULT_POINTS_PER_VIEW = 200


def default_cache_dir() -> Path:
    """$BBPOSE_VIEWPOINT_CACHE, else ~/.cache/bbpose/viewpoints."""
    return Path(os.environ.get('BBPOSE_VIEWPOINT_CACHE',
                               Path.home() / '.cache' / 'bbpose' / 'viewpoints'))


def load_viewpoint_models(models: Mapping[str, ObjectModel], cache_dir: Path | str | None = None,
                          subdivisions: int = DEFAULT_SUBDIVISIONS,
                          points_per_view: int = DEFAULT_POINTS_PER_VIEW,
                          progress: bool = True,
                          log: Callable[[str], None] | None = None
                          ) -> dict[str, ViewpointModel]:
    """
    Load the viewpoint model of each object from the cache, or build and cache it.

    Args:
        models: {name: ObjectModel}.
        cache_dir: cache folder (default ``default_cache_dir()``); an unwritable folder only
            costs the rebuild next time.
        subdivisions: icosphere level of the view directions (2: 162 views, 3: 642).
        points_per_view: contour points per view.
        progress: show a progress bar while building.
        log: optional callable for one line per model built.

    """
    if subdivisions < 0 or points_per_view < 8:
        raise InputError(f'viewpoint models need subdivisions >= 0 and >= 8 points per view, '
                         f'got {subdivisions}, {points_per_view}')
    cache_dir = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    loaded = {}
    for name, model in models.items():
        digest = mesh_digest(model.vertices, model.faces, subdivisions, points_per_view)
        path = cache_dir / f'{name}-{digest}.npz'
        if path.is_file():
            try:
                loaded[name] = ViewpointModel.load(path)
                continue
            except InputError:
                pass        # unreadable: rebuilt and overwritten below
        if log is not None:
            log(f'building the viewpoint model of {name} (once per mesh): {path}')
        with tqdm(desc=f'viewpoints {name}', unit='view', disable=not progress) as bar:
            def advance(done, total):
                bar.total = total
                bar.update(done - bar.n)
            loaded[name] = build_viewpoint_model(model.vertices, model.faces, model.diameter,
                                                 subdivisions, points_per_view, advance)
        try:
            with atomic_output(path) as tmp:
                loaded[name].save(tmp)
        except OSError as err:
            if log is not None:
                log(f'could not cache the viewpoint model of {name} in {cache_dir}: {err}')
    return loaded
