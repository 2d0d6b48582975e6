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

"""A ``torch.utils.data.Dataset`` of synthetic scenes, indexed by sample id."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TYPE_CHECKING

import torch.utils.data

if TYPE_CHECKING:
    from bbpose_ros.core.synth.scenes import SyntheticSample, SyntheticScenes


class SyntheticSceneDataset(torch.utils.data.Dataset):
    """
    ``length`` samples of a ``SyntheticScenes``: item i is ``transform(scenes.sample(i))``.

    Items are deterministic whatever the worker count or order. Each DataLoader worker
    renders with its own GL context, created on its first item. If this process has already
    rendered, forked workers cannot: pass ``multiprocessing_context='spawn'`` (or
    'forkserver') to the DataLoader; ``transform`` must then be picklable. Without a
    ``transform`` the items are
    ``SyntheticSample`` objects, which the default collate cannot batch: pass
    ``collate_fn=list`` or a ``transform`` that returns tensors (e.g. object crops).
    """

    def __init__(self, scenes: SyntheticScenes, length: int,
                 transform: Callable[[SyntheticSample], Any] | None = None) -> None:
        self.scenes = scenes
        self.length = int(length)
        self.transform = transform

    def __len__(self) -> int:
        """Return the number of samples."""
        return self.length

    def __getitem__(self, index: int) -> Any:
        """Sample ``index`` (0 <= index < length), transformed when a transform is set."""
        if not 0 <= index < self.length:
            raise IndexError(f'sample index {index} out of range 0..{self.length - 1}')
        sample = self.scenes.sample(index)
        return self.transform(sample) if self.transform is not None else sample
