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
The paper's Fig. 3: Q-Net trained with and without the q-normalization layer.

Both networks start from the same weights (the layer has none), see the same batches in the
same order and use the same optimizer; only the layer differs. Without it the Dot Product
Loss on the raw output is unbounded below (scaling the output up lowers it), so the plot also
shows, for that network, the loss of its output normalised afterwards: the figure that says
how well it actually points at the ground truth. On a GPU both train in float32, not mixed
precision: the unnormalised output's overflow is part of what the figure shows, and
float16 would overflow far sooner.
"""

from __future__ import annotations

from collections.abc import Mapping
import copy
import dataclasses
import json
import math
from pathlib import Path
import time
from typing import Any, TYPE_CHECKING

import torch

from bbpose_ros.core.nets.qnet import QNet, QNetConfig
from bbpose_ros.core.nets.quaternion import QNormalization, symmetric_dot_product_loss
from bbpose_ros.core.training.device import TrainingDevice
from bbpose_ros.core.training.loop import plot_curves
from bbpose_ros.core.training.qnet_training import QNetBatches, QNetTrainSettings

if TYPE_CHECKING:
    from bbpose_ros.core.data.models import ObjectModel
    from bbpose_ros.core.training.cache import TrainingCache
    from bbpose_ros.core.training.crop_cache import CropCache


def q_normalization_experiment(cache: TrainingCache | CropCache,
                               models: Mapping[str, ObjectModel], config: QNetConfig,
                               settings: QNetTrainSettings, run_dir: Path | str, steps: int,
                               seed: int = 0, threads: int | None = None,
                               every: int = 25,
                               device: str | torch.device = 'cpu') -> dict[str, Any]:
    """
    Train both variants for ``steps`` steps and plot their losses into ``run_dir/fig3.png``.

    Returns a summary dict (also written to ``run_dir/fig3.json``): the mean loss of the last
    ``every`` steps of each curve (None once it is not finite), the wall time, and the first
    step where the unnormalised network's loss went negative or non-finite (the plot's y
    range is cut to the meaningful 0..0.5 band). ``device``: 'cpu' or 'cuda' (float32).
    """
    if threads:
        torch.set_num_threads(threads)
    torch.manual_seed(seed)
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    device = TrainingDevice(device, mixed_precision=False)
    with_norm = QNet(dataclasses.replace(config, q_normalization=True))
    without = QNet(dataclasses.replace(config, q_normalization=False))
    without.load_state_dict(copy.deepcopy(with_norm.state_dict()))
    with_norm, without = with_norm.to(device.device), without.to(device.device)
    variants = {'with q-normalization': with_norm, 'without q-normalization': without}
    optimizers = {name: torch.optim.SGD(net.parameters(), settings.lr, momentum=0.9)
                  for name, net in variants.items()}
    sources = {name: QNetBatches(cache, config, models, settings, seed) for name in variants}
    normalize = QNormalization()
    curves = {name: [] for name in variants}
    curves['without q-normalization, output normalised afterwards'] = []
    start = time.monotonic()
    for _ in range(steps):
        for name, net in variants.items():
            images, index, candidates, valid = device.put(*sources[name].train_batch())
            net.train()
            output = net(images, index)
            loss = symmetric_dot_product_loss(output, candidates, valid).mean()
            curves[name].append(device.minimise(optimizers[name], loss))
            if net is without:
                normalised = symmetric_dot_product_loss(normalize(output.detach()), candidates,
                                                        valid)
                curves['without q-normalization, output normalised afterwards'].append(
                    float(normalised.mean()))
    series = {}
    for name, values in curves.items():
        means = [sum(values[k:k + every]) / len(values[k:k + every])
                 for k in range(0, len(values), every)]
        series[name] = ([k + every for k in range(0, len(values), every)], means)
    raw = curves['without q-normalization']
    unbounded = next((k for k, v in enumerate(raw) if not math.isfinite(v) or v < 0), None)
    plot_curves(run_dir / 'fig3.png', series,
                f'Dot Product Loss, mean of {every} iterations (SGD, lr {settings.lr:g})',
                ylim=(-0.05, 0.6))
    summary = {'steps': steps, 'seconds': round(time.monotonic() - start, 1),
               'final_loss': {name: values[-1] if math.isfinite(values[-1]) else None
                              for name, (_, values) in series.items()},
               'raw_loss_negative_or_nonfinite_from_step': unbounded}
    (run_dir / 'fig3.json').write_text(json.dumps(summary, indent=1) + '\n')
    return summary
