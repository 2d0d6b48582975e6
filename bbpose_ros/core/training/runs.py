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
Training runs of Q-Net, the detector and the dense net: build, train, checkpoint, export.

Each run folder gets ``checkpoint.pt`` (resumable), ``log.csv``, ``train.log``, ``loss.png``
and the exported weight file (``qnet.pt`` / ``detector.pt`` / ``dense.pt``, with metadata, see
``core.inference.weights``), re-exported at every checkpoint; ``export`` copies it elsewhere
too. The detector's second stage trains in a run of its own and is exported with its first
stage in one ``detector.pt``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, replace
from pathlib import Path
import shutil
import subprocess
import sys
from typing import TYPE_CHECKING

import torch

from bbpose_ros.core.errors import InputError
from bbpose_ros.core.files import atomic_output
from bbpose_ros.core.inference.weights import save_weights
from bbpose_ros.core.nets.dense import DenseConfig, DenseNet
from bbpose_ros.core.nets.detector import CenterBoxNet, DetectorConfig
from bbpose_ros.core.nets.efficientnet_lite import EfficientNetLite0, load_imagenet_trunks
from bbpose_ros.core.nets.qnet import QNet, QNetConfig
from bbpose_ros.core.training.dense_training import (dense_step, dense_validation,
                                                     DenseBatches, DenseTrainSettings,
                                                     freeze_early_blocks)
from bbpose_ros.core.training.detector_training import (detector_step, detector_validation,
                                                        DetectorBatches, DetectorTrainSettings)
from bbpose_ros.core.training.device import TrainingDevice
from bbpose_ros.core.training.loop import run_loop, RunLog
from bbpose_ros.core.training.qnet_training import (qnet_step, qnet_validation, QNetBatches,
                                                    QNetTrainSettings)
from bbpose_ros.core.training.verifier_training import (CandidateCrops, verifier_step,
                                                        verifier_validation, VerifierBatches,
                                                        VerifierTrainSettings)

if TYPE_CHECKING:
    from bbpose_ros.core.data.models import ObjectModel
    from bbpose_ros.core.training.cache import TrainingCache
    from bbpose_ros.core.training.crop_cache import CropCache
    from bbpose_ros.core.training.real_validation import RealCrops, RealDenseCrops, \
        RealDetections


def git_commit() -> str:
    """Commit hash of the working tree's HEAD, or 'unknown' outside a git checkout."""
    try:
        return subprocess.run(['git', 'rev-parse', 'HEAD'], capture_output=True, text=True,
                              check=True, cwd=Path(__file__).parent).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return 'unknown'


def _prepare(run_dir, seed, threads, device):
    """Seed, set the CPU threads, log the command; return the run's TrainingDevice."""
    torch.manual_seed(seed)
    if threads:
        torch.set_num_threads(threads)
    device = TrainingDevice(device)
    RunLog(run_dir).text(f'command: {" ".join(sys.argv)} (device {device}, torch threads '
                         f'{torch.get_num_threads()})')
    return device


def _exporter(run_dir, network, kind, training, export, validation, base=None,
              export_input_size=None):
    """
    Return a checkpoint hook that writes the weight file (and its copy).

    The file's training record is ``training`` with the step and latest ``validation``; with
    a ``base`` record (the first stage's, for a second stage), ``base`` with that record as
    its ``verifier`` entry. With ``export_input_size`` (a detector's (width, height)) the
    copy records that input size instead of the training one.
    """
    def export_weights(step):
        record = dict(training, steps=step, validation=validation)
        if base is not None:
            record = dict(base, verifier=record)
        path = Path(run_dir) / f'{kind}.pt'
        save_weights(path, network, kind, record)
        if export and export_input_size:
            save_weights(export, network, kind, record,
                         replace(network.config, input_size=tuple(export_input_size)))
        elif export:
            with atomic_output(export) as tmp:
                shutil.copyfile(path, tmp)
    return export_weights


def _validated(validate, store):
    """Wrap ``validate`` so that its latest figures are kept in ``store``."""
    def run():
        figures = validate()
        store.clear()
        store.update(figures)
        return figures
    return run


def train_qnet(cache: TrainingCache | CropCache, models: Mapping[str, ObjectModel],
               config: QNetConfig, settings: QNetTrainSettings, run_dir: Path | str,
               steps: int, seconds: float | None = None, seed: int = 0,
               threads: int | None = None, export: Path | str | None = None, every: int = 500,
               progress: bool = True, real_crops: RealCrops | None = None,
               device: str | torch.device = 'cpu', init: QNet | None = None) -> QNet:
    """
    Train (or resume) a Q-Net on a TrainingCache or CropCache; returns the network.

    ``config`` is a QNetConfig, ``settings`` a QNetTrainSettings; budgets as in
    ``loop.run_loop``. The weight file is written to ``run_dir/qnet.pt`` (and ``export``).
    ``real_crops`` (a ``RealCrops``) adds real-frame figures to every validation, measured
    on the CPU. ``device``: 'cpu' or 'cuda' (with mixed precision, see ``device.py``).
    ``init``: a trained Q-Net of the same config to start from (``start_weights``).
    """
    device = _prepare(run_dir, seed, threads, device)
    network, optimizer = _start_network(QNet(config), settings, device, init)
    batches = QNetBatches(cache, config, models, settings, seed)
    validation = {}
    training = dict(_crop_run_record(cache, settings, steps, seed, device),
                    init=_init_command(init))
    run_loop(run_dir, network, optimizer,
             lambda step: qnet_step(network, optimizer, batches, device), steps, seconds,
             settings.lr,
             validate=_validated(lambda: _qnet_figures(network, batches, real_crops, device),
                                 validation),
             every=every, on_checkpoint=_exporter(run_dir, network, 'qnet', training, export,
                                                  validation),
             progress=progress, device=device)
    return network


def train_dense(cache: CropCache, models: Mapping[str, ObjectModel], config: DenseConfig,
                settings: DenseTrainSettings, run_dir: Path | str, steps: int,
                seconds: float | None = None, seed: int = 0, threads: int | None = None,
                export: Path | str | None = None, every: int = 500, progress: bool = True,
                real_crops: RealDenseCrops | None = None,
                device: str | torch.device = 'cpu', init: DenseNet | None = None) -> DenseNet:
    """
    Train (or resume) a dense net on a CropCache with dense targets; returns the network.

    As ``train_qnet``: the weight file is ``run_dir/dense.pt`` (and ``export``);
    ``real_crops`` (a ``RealDenseCrops``) adds real-frame figures to every validation;
    ``init`` is a trained dense net of the same config to start from (``start_weights``).
    """
    device = _prepare(run_dir, seed, threads, device)
    network = DenseNet(config)
    freeze_early_blocks(network, settings.frozen_blocks)
    network, optimizer = _start_network(network, settings, device, init)
    batches = DenseBatches(cache, config, models, settings, seed)
    validation = {}
    training = dict(_crop_run_record(cache, settings, steps, seed, device),
                    init=_init_command(init))

    def figures():
        values = dense_validation(network, batches, device)
        if real_crops is not None:
            values.update(real_crops.figures(network.cpu()))
            network.to(device.device)
        return values

    run_loop(run_dir, network, optimizer,
             lambda step: dense_step(network, optimizer, batches, device), steps, seconds,
             settings.lr, validate=_validated(figures, validation), every=every,
             on_checkpoint=_exporter(run_dir, network, 'dense', training, export, validation),
             progress=progress, device=device)
    return network


def start_weights(network: torch.nn.Module, init: torch.nn.Module | None) -> torch.nn.Module:
    """
    Give a new network its starting weights: ImageNet trunks, or a trained network's.

    Args:
        network: the untrained network.
        init: a trained network of the same kind, objects and architecture (fine-tuning),
            or None: the ImageNet trunks of a 'lite0' backbone, the rest as initialised.

    Returns:
        ``network``, its weights set.

    Raises:
        InputError: ``init`` does not fit the network (other objects or architecture).

    """
    if init is None:
        load_imagenet_trunks(network)
        return network
    try:
        network.load_state_dict(init.state_dict())
    except RuntimeError as err:
        raise InputError(f'the network to start from does not fit {network.config}: '
                         f'{str(err).splitlines()[0]}') from err
    return network


def _init_command(init):
    """Return the training command of the network a run started from (None: ImageNet)."""
    return None if init is None else getattr(init, 'metadata', {}).get('training', {}).get(
        'command')


def _start_network(network, settings, device, init=None):
    """Set a network's start (``start_weights``), put it on ``device``; return it and AdamW."""
    start_weights(network, init)
    network = network.to(device.device, memory_format=torch.channels_last)
    optimizer = torch.optim.AdamW(parameter_groups(network, settings.trunk_lr_scale),
                                  settings.lr, weight_decay=settings.weight_decay)
    return network, optimizer


def _crop_run_record(cache, settings, steps, seed, device):
    """Return the weight file's training record of a Q-Net or dense run on a cache."""
    return {'command': ' '.join(sys.argv), 'git_commit': git_commit(), 'seed': seed,
            'settings': asdict(settings), 'total_steps': steps, 'device': device.device.type,
            'cache_objects': cache.objects, 'cache_instances': int(len(cache.visib))}


def parameter_groups(network, trunk_lr_scale):
    """
    Optimizer groups: pretrained Lite0 trunks at ``trunk_lr_scale`` times the rate (0: frozen).

    ``run_loop`` multiplies a group's scheduled rate by its ``lr_scale``.
    """
    trunk = [p for m in network.modules() if isinstance(m, EfficientNetLite0)
             for p in m.parameters()]
    if not trunk:
        return [{'params': list(network.parameters())}]
    trunk_ids = {id(p) for p in trunk}
    rest = [p for p in network.parameters() if id(p) not in trunk_ids]
    if trunk_lr_scale <= 0:
        for parameter in trunk:
            parameter.requires_grad_(False)
        return [{'params': rest}]
    return [{'params': rest}, {'params': trunk, 'lr_scale': trunk_lr_scale}]


def _qnet_figures(network, batches, real_crops, device):
    figures = qnet_validation(network, batches, device)
    if real_crops is not None:
        figures.update(real_crops.figures(network))
    return figures


def train_detector(cache: TrainingCache, config: DetectorConfig,
                   settings: DetectorTrainSettings, run_dir: Path | str, steps: int,
                   seconds: float | None = None, seed: int = 0, threads: int | None = None,
                   export: Path | str | None = None, every: int = 500,
                   export_input_size: tuple[int, int] | None = None,
                   progress: bool = True, device: str | torch.device = 'cpu',
                   init: CenterBoxNet | None = None) -> CenterBoxNet:
    """
    Train (or resume) the detector on a TrainingCache; as ``train_qnet`` otherwise.

    A 'lite0' backbone starts from ImageNet and learns at ``settings.trunk_lr_scale`` times
    the head's rate (0: frozen). ``export_input_size``: (width, height) the ``export`` copy
    is run at (multiples of 16), when not the cache's. ``init``: a trained detector of the
    same objects and architecture to start from instead (fine-tuning; a resumed run takes
    its checkpoint's weights).
    """
    device = _prepare(run_dir, seed, threads, device)
    network, optimizer = _start_network(CenterBoxNet(config), settings, device, init)
    batches = DetectorBatches(cache, config, settings, seed)
    validation = {}
    training = {'command': ' '.join(sys.argv), 'git_commit': git_commit(), 'seed': seed,
                'settings': asdict(settings), 'total_steps': steps,
                'device': device.device.type, 'cache_scenes': int(len(cache.images)),
                'init': _init_command(init)}
    run_loop(run_dir, network, optimizer,
             lambda step: detector_step(network, optimizer, batches, device), steps, seconds,
             settings.lr,
             validate=_validated(lambda: detector_validation(network, batches, device),
                                 validation),
             every=every, on_checkpoint=_exporter(run_dir, network, 'detector', training,
                                                  export, validation,
                                                  export_input_size=export_input_size),
             progress=progress, device=device)
    return network


def with_verifier(detector: CenterBoxNet, channels: Sequence[int], crop_size: int,
                  context: float, candidates: int) -> CenterBoxNet:
    """
    Copy a trained CenterBoxNet and give it a new, untrained second stage.

    The first stage's weights and metadata are kept; the second stage is configured by
    ``channels``, ``crop_size``, ``context`` and ``candidates`` (see DetectorConfig).
    """
    config = replace(detector.config, verifier_channels=tuple(channels),
                     verifier_crop_size=crop_size, verifier_context=context,
                     candidates=candidates)
    cascade = CenterBoxNet(config)
    first = {k: v for k, v in detector.state_dict().items() if not k.startswith('verifier.')}
    cascade.load_state_dict(first, strict=False)     # the same config: only verifier.* missing
    cascade.metadata = detector.metadata
    return cascade


def train_verifier(cache: TrainingCache, cascade: CenterBoxNet,
                   settings: VerifierTrainSettings, run_dir: Path | str, steps: int,
                   seconds: float | None = None, seed: int = 0, threads: int | None = None,
                   export: Path | str | None = None, every: int = 500, progress: bool = True,
                   real_frames: RealDetections | None = None,
                   device: str | torch.device = 'cpu') -> CenterBoxNet:
    """
    Train (or resume) the second stage of ``cascade`` (``with_verifier``) on a TrainingCache.

    The first stage stays as it is. ``settings`` is a VerifierTrainSettings; budgets as in
    ``loop.run_loop``; ``real_frames`` (a ``RealDetections``) adds the real recall to every
    validation. The weight file, both stages, is ``run_dir/detector.pt`` (and ``export``).
    ``device`` as in ``train_qnet``.
    """
    device = _prepare(run_dir, seed, threads, device)
    cascade = cascade.to(device.device, memory_format=torch.channels_last)
    candidates = CandidateCrops(cascade, cache, settings, seed, device, progress)
    RunLog(run_dir).text(f'{len(candidates.labels)} candidate crops from {candidates.scenes} '
                         f'scenes, {int((candidates.labels > 0).sum())} of them on an object')
    verifier = cascade.verifier
    optimizer = torch.optim.AdamW(verifier.parameters(), settings.lr,
                                  weight_decay=settings.weight_decay)
    batches = VerifierBatches(candidates, settings, seed)
    validation = {}
    training = {'command': ' '.join(sys.argv), 'git_commit': git_commit(), 'seed': seed,
                'settings': asdict(settings), 'total_steps': steps,
                'device': device.device.type, 'cache_scenes': int(len(cache.images)),
                'candidate_crops': int(len(candidates.labels))}

    def figures():
        result = verifier_validation(verifier, batches, device)
        if real_frames is not None:
            result.update(real_frames.figures(cascade))
        return result

    run_loop(run_dir, verifier, optimizer,
             lambda step: verifier_step(verifier, optimizer, batches, device), steps, seconds,
             settings.lr, validate=_validated(figures, validation), every=every,
             on_checkpoint=_exporter(run_dir, cascade, 'detector', training, export,
                                     validation, base=cascade.metadata['training']),
             progress=progress, device=device)
    return cascade
