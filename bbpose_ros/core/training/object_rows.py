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
Networks that learn a new object while keeping what they know: new output rows only.

Each of the three networks ends in one layer with a block of rows per object (the
detector's heatmap: 1 channel; Q-Net's head: 5 H values for H hypotheses; the dense net's
output: 5 channels), after trunks and decoders that every object shares. ``with_objects``
gives a network for another list of objects: a known object keeps its rows, a new one
starts from the mean of the known objects' rows (for the detector a heatmap that fires on
any known object, which training then narrows to the new one). ``fit_new_rows`` trains
just the new rows: the shared layers are frozen (batch-norm statistics included) and run
once over the renders of the new object (``passes`` augmented copies of each), and the new
rows then learn from those cached features (``head_fitting``), so the known objects'
outputs stay bit for bit what they were.

Why rows only: the shared layers run forward once, so training takes minutes on a CPU,
and it cannot cost the known objects any accuracy. What it cannot do: learn features the
shared layers lack; a new object unlike the known ones gets the features they taught.
"""

from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace

import numpy as np
import torch
from torch import nn
import torch.nn.functional as F

from bbpose_ros.core.data.models import ObjectModel
from bbpose_ros.core.nets.dense import DenseNet, PER_OBJECT
from bbpose_ros.core.nets.detector import CenterBoxNet
from bbpose_ros.core.nets.qnet import QNet
from bbpose_ros.core.training.cache import TrainingCache
from bbpose_ros.core.training.crop_cache import CropCache
from bbpose_ros.core.training.dense_training import dense_loss, dense_validation, DenseBatches
from bbpose_ros.core.training.detector_training import (detector_validation, DetectorBatches,
                                                        focal_loss)
from bbpose_ros.core.training.device import TrainingDevice
from bbpose_ros.core.training.head_fitting import cache_features, fit_tensors
from bbpose_ros.core.training.qnet_training import qnet_loss, qnet_validation, QNetBatches
from bbpose_ros.core.training.settings import (DenseTrainSettings, DetectorTrainSettings,
                                               QNetTrainSettings, RowTraining)
from bbpose_ros.core.util.errors import InputError

Network = CenterBoxNet | QNet | DenseNet

# The layer holding each network's per-object rows (attribute name).
OBJECT_LAYERS = {CenterBoxNet: 'heatmap', QNet: 'head', DenseNet: 'output'}


def object_layer_name(network: Network) -> str:
    """Return the attribute name of ``network``'s per-object output layer."""
    if isinstance(network, CenterBoxNet) and network.verifier is not None:
        raise InputError('a detector with a second stage (verifier) cannot be given new '
                         'objects: its crop classifier has a class per object too')
    return OBJECT_LAYERS[type(network)]


def rows_per_object(network: Network) -> int:
    """Output rows (channels or features) each object has in the per-object layer."""
    layer = getattr(network, object_layer_name(network))
    return layer.weight.shape[0] // len(network.config.objects)


def with_objects(network: Network, objects: Sequence[str]) -> Network:
    """
    Return a copy of ``network`` for ``objects`` (names, in their output order).

    Known objects keep their rows; an object the network does not know starts from the
    mean of the known objects' rows. The rest of the weights are copied. Objects left out
    of ``objects`` lose their rows (a leave-one-out base).

    Raises:
        InputError: no object is known to ``network``, or a name repeats.

    """
    objects = tuple(objects)
    known = list(network.config.objects)
    if len(set(objects)) != len(objects):
        raise InputError(f'object names repeat: {", ".join(objects)}')
    if not any(name in known for name in objects):
        raise InputError(f'none of {", ".join(objects)} is known to the network '
                         f'({", ".join(known)})')
    name, width = object_layer_name(network), rows_per_object(network)
    state = network.state_dict()
    grown = {}
    for part in ('weight', 'bias'):
        rows = state[f'{name}.{part}'].reshape(len(known), width,
                                               *state[f'{name}.{part}'].shape[1:])
        mean = rows.mean(dim=0)
        grown[f'{name}.{part}'] = torch.cat([rows[known.index(n)] if n in known else mean
                                             for n in objects])
    copy = type(network)(replace(network.config, objects=objects))
    copy.load_state_dict({**state, **grown})
    return copy


class _RowTask:
    """One network's batches, cached features and loss on the new rows' outputs."""

    chunk = 16

    def __init__(self, batches, network, new_index):
        self.batches, self.network = batches, network
        self.new_index = new_index     # (objects,) rank among the new rows, -1: known

    def units(self) -> np.ndarray:
        """Return the training inputs (scenes or crops) to cache."""
        return self.batches.train_ids

    def encode(self, units, strength):
        """(features, targets...) of ``units`` augmented at ``strength``: batch axis first."""
        raise NotImplementedError

    def loss(self, outputs, *targets):
        """Scalar loss of the new rows' ``outputs`` (all new objects' rows)."""
        raise NotImplementedError


class _DetectorTask(_RowTask):
    chunk = 4

    def units(self):
        return self.batches.train_scenes

    def encode(self, units, strength):
        images, heat, _, _ = self.batches.make(units, strength)
        channels = torch.from_numpy(np.flatnonzero(self.new_index >= 0))
        return self.network.features(images), heat[:, channels]

    def loss(self, outputs, heat):
        return focal_loss(outputs, heat.float())


class _QNetTask(_RowTask):
    chunk = 64

    def encode(self, units, strength):
        settings = self.batches.settings
        images, index, candidates, valid = self.batches.make(
            units, self.batches.rng, settings.box_sigma, strength)
        return (self.network.features(images), torch.from_numpy(self.new_index)[index],
                candidates, valid)

    def loss(self, outputs, new, candidates, valid):
        width = self.network.head_width
        columns = new.unsqueeze(1) * width + torch.arange(width)
        raw = outputs.gather(1, columns)
        return qnet_loss(self.network.split_hypotheses(raw), candidates, valid).mean()


class _DenseTask(_RowTask):
    chunk = 32

    def encode(self, units, strength):
        images, index, coordinates, visible, amodal = self.batches.make(units, strength)
        return (self.network.features(images), torch.from_numpy(self.new_index)[index],
                coordinates, visible, amodal)

    def loss(self, outputs, new, coordinates, visible, amodal):
        index = (new.view(-1, 1, 1, 1) * PER_OBJECT +
                 torch.arange(PER_OBJECT).view(1, -1, 1, 1)).expand(-1, -1, *outputs.shape[2:])
        maps = outputs.gather(1, index)
        loss, _ = dense_loss(maps, coordinates, visible, amodal,
                             self.batches.settings.coordinate_weight)
        return loss.mean()


# Per network: its batches (from cache, config, models, settings, seed), row task and
# validation on held-out renders.
_KINDS: dict[type, tuple[Callable, type, Callable]] = {
    CenterBoxNet: (lambda cache, config, models, settings, seed:
                   DetectorBatches(cache, config, settings, seed),
                   _DetectorTask, detector_validation),
    QNet: (QNetBatches, _QNetTask, qnet_validation),
    DenseNet: (lambda cache, config, models, settings, seed:
               DenseBatches(cache, config, models, settings, seed, require_all=False),
               _DenseTask, dense_validation),
}


def fit_new_rows(network: Network, new_objects: Sequence[str],
                 cache: TrainingCache | CropCache, models: Mapping[str, ObjectModel],
                 settings: DetectorTrainSettings | QNetTrainSettings | DenseTrainSettings,
                 rows: RowTraining, seed: int = 0, progress: bool = True) -> dict[str, float]:
    """
    Train ``network``'s rows of ``new_objects`` in place; return held-out figures.

    Args:
        network: a network that already has rows for ``new_objects`` (``with_objects``).
        new_objects: the names whose rows learn; every other weight stays as it is.
        cache: renders of the new objects: a scene cache (detector) or a crop cache with
            dense targets (Q-Net, dense net).
        models: {name: ObjectModel} of the network's objects (symmetries, model boxes).
        settings: the network's train settings: batch draws, augmentation, held-out share
            (``val_fraction``), Q-Net's box jitter and targets; their rates are not used.
        rows: RowTraining.
        seed: seed of the draws.
        progress: show tqdm bars.

    Returns:
        The network's validation figures on the held-out renders (its ``*_validation``).

    """
    objects = list(network.config.objects)
    missing = [name for name in new_objects if name not in objects]
    if missing:
        raise InputError(f'the network has no rows for {", ".join(missing)}')
    make_batches, task_type, validate = _KINDS[type(network)]
    batches = make_batches(cache, network.config, models, settings, seed)
    is_new = np.array([name in new_objects for name in objects])
    new_index = np.where(is_new, np.cumsum(is_new) - 1, -1)    # rank among the new rows
    task = task_type(batches, network, new_index)
    network.eval()
    units = task.units()
    chunks = [units[i:i + task.chunk] for i in range(0, len(units), task.chunk)]
    cached = cache_features(lambda chunk, copy: task.encode(chunk, settings.augment_strength),
                            chunks, rows.passes, progress)
    layer = getattr(network, object_layer_name(network))
    width = rows_per_object(network)
    chosen = torch.from_numpy(np.concatenate([np.arange(k * width, (k + 1) * width)
                                              for k in np.flatnonzero(new_index >= 0)]))
    start = (layer.weight.detach()[chosen], layer.bias.detach()[chosen])
    apply = F.linear if isinstance(layer, nn.Linear) else F.conv2d
    features, targets = cached[0], cached[1:]

    def loss_of(tensors, pick):
        return task.loss(apply(features[pick].float(), *tensors),
                         *(part[pick] for part in targets))

    runs = [fit_tensors(start, (True, True), loss_of, len(features), rows,
                        np.random.default_rng([seed, run]), 'new rows', progress)
            for run in range(rows.seeds)]
    weight, bias = (torch.stack(part).mean(dim=0) for part in zip(*runs))
    with torch.no_grad():
        layer.weight[chosen] = weight
        layer.bias[chosen] = bias
    return validate(network, batches, TrainingDevice('cpu'))
