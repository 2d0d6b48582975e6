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
Output layers fitted on cached features: the shared layers run once, the fitted ones learn.

``bbpose add-object`` (an object's new rows, ``object_rows``) and ``bbpose adapt`` (the
detector's heads and Q-Net's rows, ``adaptation.students``) keep a network's shared layers
frozen and train only layers that read them. The frozen layers run once over ``passes``
augmented copies of the training inputs (``cache_features``); the fitted tensors then learn
from those features with Adam, a cosine rate and batches drawn without replacement
(``fit_tensors``). Both take their settings from a ``FeatureTraining``.
"""

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from bbpose_ros.core.training.loop import cosine_lr
from bbpose_ros.core.training.settings import FeatureTraining

# encode(chunk, copy) -> (features, *targets): one chunk of training inputs, augmented copy
# ``copy`` (0-based), batch axis first.
Encoder = Callable[[Any, int], Sequence[torch.Tensor]]
# loss_of(tensors, pick) -> scalar loss of the cached samples ``pick`` ((B,) int64).
LossOf = Callable[[list[torch.Tensor], torch.Tensor], torch.Tensor]


def cache_features(encode: Encoder, chunks: Sequence[Any], passes: int,
                   progress: bool = True) -> list[torch.Tensor]:
    """
    Encode each of ``chunks`` ``passes`` times (pass after pass); return the columns joined.

    Returns:
        [features, *targets], each concatenated along the batch axis; the features are
        stored as float16 (the fits read them back as float32).

    """
    work = [(copy, chunk) for copy in range(passes) for chunk in chunks]
    parts = []
    with torch.inference_mode():
        for copy, chunk in tqdm(work, desc='features', unit='batch', disable=not progress):
            features, *targets = encode(chunk, copy)
            parts.append((features.to(torch.float16), *targets))
    return [torch.cat(column) for column in zip(*parts)]


def fit_tensors(start: Sequence[torch.Tensor], learns: Sequence[bool], loss_of: LossOf,
                size: int, training: FeatureTraining, rng: np.random.Generator,
                desc: str = 'fit', progress: bool = True) -> list[torch.Tensor]:
    """
    Train copies of ``start`` on ``size`` cached samples; return them, detached.

    Args:
        start: the tensors' start values (left as they are).
        learns: per tensor, whether it learns; the others stay at their start.
        loss_of: the loss of a batch with the tensors being trained.
        size: number of cached samples the batches are drawn from.
        training: its steps, batch, lr and warmup (a cosine rate, ``loop.cosine_lr``).
        rng: the batch draws.
        desc: the progress bar's label.
        progress: show a tqdm bar.

    """
    tensors = [part.clone().requires_grad_(learn) for part, learn in zip(start, learns)]
    optimizer = torch.optim.Adam([t for t in tensors if t.requires_grad], training.lr)
    bar = tqdm(range(training.steps), desc=desc, unit='step', disable=not progress)
    for step in bar:
        for group in optimizer.param_groups:
            group['lr'] = cosine_lr(training.lr, step, training.steps, training.warmup)
        pick = torch.from_numpy(rng.choice(size, min(training.batch, size), replace=False))
        loss = loss_of(tensors, pick)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        bar.set_postfix(loss=f'{float(loss.detach()):.4f}', refresh=False)
    return [t.detach() for t in tensors]
