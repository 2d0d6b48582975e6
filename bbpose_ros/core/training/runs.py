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
too. A ``TrainingRun`` says where a run writes, how long it goes and what it runs on; its
network's settings are a ``settings`` class. The detector's second stage trains in a run of
its own and is exported with its first stage in one ``detector.pt``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
import shutil
import subprocess
import sys
from typing import Any, TYPE_CHECKING

import torch

from bbpose_ros.core.inference.weights import save_weights
from bbpose_ros.core.nets.dense import DenseConfig, DenseNet
from bbpose_ros.core.nets.detector import CenterBoxNet, DetectorConfig
from bbpose_ros.core.nets.efficientnet_lite import EfficientNetLite0, load_imagenet_trunks
from bbpose_ros.core.nets.qnet import QNet, QNetConfig
from bbpose_ros.core.training.dense_training import (dense_step, dense_validation,
                                                     DenseBatches, freeze_early_blocks)
from bbpose_ros.core.training.detector_training import (detector_step, detector_validation,
                                                        DetectorBatches)
from bbpose_ros.core.training.device import TrainingDevice
from bbpose_ros.core.training.loop import run_loop, RunLog
from bbpose_ros.core.training.qnet_training import qnet_step, qnet_validation, QNetBatches
from bbpose_ros.core.training.verifier_training import (CandidateCrops, verifier_step,
                                                        verifier_validation, VerifierBatches)
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.core.util.files import atomic_output

if TYPE_CHECKING:
    from bbpose_ros.core.data.models import ObjectModel
    from bbpose_ros.core.training.cache import TrainingCache
    from bbpose_ros.core.training.crop_cache import CropCache
    from bbpose_ros.core.training.real_validation import RealCrops, RealDenseCrops, \
        RealDetections
    from bbpose_ros.core.training.settings import (DenseTrainSettings, DetectorTrainSettings,
                                                   QNetTrainSettings, TrainSettings,
                                                   VerifierTrainSettings)


def git_commit() -> str:
    """Commit hash of the working tree's HEAD, or 'unknown' outside a git checkout."""
    try:
        return subprocess.run(['git', 'rev-parse', 'HEAD'], capture_output=True, text=True,
                              check=True, cwd=Path(__file__).parent).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return 'unknown'


@dataclass(frozen=True)
class TrainingRun:
    """
    Where a training run writes, how long it goes and what it runs on.

    What every network's run takes besides its data, network and settings.

    Attributes:
        run_dir: run folder: ``checkpoint.pt`` (resumed), logs, plot and the weight file.
        steps: total steps (the learning-rate schedule spans them).
        seconds: stop after this many seconds of this call (resume later); None: no limit.
        seed: seed of the initialisation and the batch draws.
        threads: torch's CPU threads; None or 0: torch's default.
        export: also copy the weight file here at every checkpoint; None: not.
        every: steps between checkpoints (each validates and writes the weight file).
        progress: show a progress bar.
        device: 'cpu' or 'cuda' (with mixed precision, see ``device.py``).

    """

    run_dir: Path | str
    steps: int
    seconds: float | None = None
    seed: int = 0
    threads: int | None = None
    export: Path | str | None = None
    every: int = 500
    progress: bool = True
    device: str | torch.device = 'cpu'

    def start(self) -> TrainingDevice:
        """Seed, set the CPU threads, log the command; return the run's TrainingDevice."""
        torch.manual_seed(self.seed)
        if self.threads:
            torch.set_num_threads(self.threads)
        device = TrainingDevice(self.device)
        RunLog(self.run_dir).text(f'command: {" ".join(sys.argv)} (device {device}, torch '
                                  f'threads {torch.get_num_threads()})')
        return device

    def record(self, settings: TrainSettings, device: TrainingDevice,
               **details: Any) -> dict[str, Any]:
        """Return the weight file's training record of this run, with ``details`` added."""
        return {'command': ' '.join(sys.argv), 'git_commit': git_commit(), 'seed': self.seed,
                'settings': asdict(settings), 'total_steps': self.steps,
                'device': device.device.type, **details}


def _exporter(run, network, kind, training, validation, base=None, export_input_size=None):
    """
    Return a checkpoint hook that writes the weight file (and its copy, ``run.export``).

    The file's training record is ``training`` with the step and latest ``validation``; with
    a ``base`` record (the first stage's, for a second stage), ``base`` with that record as
    its ``verifier`` entry. With ``export_input_size`` (a detector's (width, height)) the
    copy records that input size instead of the training one.
    """
    def export_weights(step):
        record = dict(training, steps=step, validation=validation)
        if base is not None:
            record = dict(base, verifier=record)
        path = Path(run.run_dir) / f'{kind}.pt'
        save_weights(path, network, kind, record)
        if run.export and export_input_size:
            save_weights(run.export, network, kind, record,
                         replace(network.config, input_size=tuple(export_input_size)))
        elif run.export:
            with atomic_output(run.export) as tmp:
                shutil.copyfile(path, tmp)
    return export_weights


def _train(run, device, network, optimizer, step, lr, validate, kind, training, real=None,
           exported=None, **export):
    """
    Run the loop of ``run``: ``step(step_index)`` until done, validating at checkpoints.

    ``network`` and ``optimizer`` are checkpointed, the optimizer's groups following the
    cosine schedule of peak ``lr``. Each checkpoint validates (``validate()``'s figures and,
    with ``real``, ``real()``'s on real frames) and writes ``exported`` (default
    ``network``) as the weight file of ``kind`` with the record ``training`` and the latest
    figures; ``export``: ``_exporter``'s ``base`` and ``export_input_size``.
    """
    validation = {}

    def validated():
        figures = validate()
        if real is not None:
            figures.update(real())
        validation.clear()
        validation.update(figures)
        return figures

    hook = _exporter(run, network if exported is None else exported, kind, training,
                     validation, **export)
    run_loop(run.run_dir, network, optimizer, step, run.steps, run.seconds, lr,
             validate=validated, every=run.every, on_checkpoint=hook, progress=run.progress,
             device=device)


def train_qnet(cache: TrainingCache | CropCache, models: Mapping[str, ObjectModel],
               config: QNetConfig, settings: QNetTrainSettings, run: TrainingRun,
               real_crops: RealCrops | None = None, init: QNet | None = None) -> QNet:
    """
    Train (or resume) a Q-Net on a TrainingCache or CropCache; returns the network.

    ``config`` is a QNetConfig, ``settings`` a QNetTrainSettings, ``run`` the TrainingRun.
    The weight file is written to ``run_dir/qnet.pt`` (and ``export``). ``real_crops`` (a
    ``RealCrops``) adds real-frame figures to every validation, measured on the CPU.
    ``init``: a trained Q-Net of the same config to start from (``start_weights``).
    """
    device = run.start()
    network, optimizer = _start_network(QNet(config), settings, device, init)
    batches = QNetBatches(cache, config, models, settings, run.seed)
    training = run.record(settings, device, **_cache_record(cache), init=_init_command(init))
    _train(run, device, network, optimizer,
           lambda step: qnet_step(network, optimizer, batches, device), settings.lr,
           lambda: qnet_validation(network, batches, device), 'qnet', training,
           real=None if real_crops is None else lambda: real_crops.figures(network))
    return network


def train_dense(cache: CropCache, models: Mapping[str, ObjectModel], config: DenseConfig,
                settings: DenseTrainSettings, run: TrainingRun,
                real_crops: RealDenseCrops | None = None,
                init: DenseNet | None = None) -> DenseNet:
    """
    Train (or resume) a dense net on a CropCache with dense targets; returns the network.

    As ``train_qnet``: the weight file is ``run_dir/dense.pt`` (and ``export``);
    ``real_crops`` (a ``RealDenseCrops``) adds real-frame figures to every validation;
    ``init`` is a trained dense net of the same config to start from (``start_weights``).
    """
    device = run.start()
    network = DenseNet(config)
    freeze_early_blocks(network, settings.frozen_blocks)
    network, optimizer = _start_network(network, settings, device, init)
    batches = DenseBatches(cache, config, models, settings, run.seed)
    training = run.record(settings, device, **_cache_record(cache), init=_init_command(init))

    def real_figures():      # measured on the CPU
        values = real_crops.figures(network.cpu())
        network.to(device.device)
        return values

    _train(run, device, network, optimizer,
           lambda step: dense_step(network, optimizer, batches, device), settings.lr,
           lambda: dense_validation(network, batches, device), 'dense', training,
           real=None if real_crops is None else real_figures)
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


def _cache_record(cache):
    """Return what a Q-Net or dense run's record says of its crop or scene cache."""
    return {'cache_objects': cache.objects, 'cache_instances': int(len(cache.visib))}


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


def train_detector(cache: TrainingCache, config: DetectorConfig,
                   settings: DetectorTrainSettings, run: TrainingRun,
                   export_input_size: tuple[int, int] | None = None,
                   init: CenterBoxNet | None = None) -> CenterBoxNet:
    """
    Train (or resume) the detector on a TrainingCache; as ``train_qnet`` otherwise.

    A 'lite0' backbone starts from ImageNet and learns at ``settings.trunk_lr_scale`` times
    the head's rate (0: frozen). ``export_input_size``: (width, height) the ``export`` copy
    is run at (multiples of 16), when not the cache's. ``init``: a trained detector of the
    same objects and architecture to start from instead (fine-tuning; a resumed run takes
    its checkpoint's weights).
    """
    device = run.start()
    network, optimizer = _start_network(CenterBoxNet(config), settings, device, init)
    batches = DetectorBatches(cache, config, settings, run.seed)
    training = run.record(settings, device, cache_scenes=int(len(cache.images)),
                          init=_init_command(init))
    _train(run, device, network, optimizer,
           lambda step: detector_step(network, optimizer, batches, device), settings.lr,
           lambda: detector_validation(network, batches, device), 'detector', training,
           export_input_size=export_input_size)
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
                   settings: VerifierTrainSettings, run: TrainingRun,
                   real_frames: RealDetections | None = None) -> CenterBoxNet:
    """
    Train (or resume) the second stage of ``cascade`` (``with_verifier``) on a TrainingCache.

    The first stage stays as it is. ``settings`` is a VerifierTrainSettings, ``run`` the
    TrainingRun; ``real_frames`` (a ``RealDetections``) adds the real recall to every
    validation. The weight file, both stages, is ``run_dir/detector.pt`` (and ``export``).
    """
    device = run.start()
    cascade = cascade.to(device.device, memory_format=torch.channels_last)
    candidates = CandidateCrops(cascade, cache, settings, run.seed, device, run.progress)
    RunLog(run.run_dir).text(f'{len(candidates.labels)} candidate crops from '
                             f'{candidates.scenes} scenes, '
                             f'{int((candidates.labels > 0).sum())} of them on an object')
    verifier = cascade.verifier
    optimizer = torch.optim.AdamW(verifier.parameters(), settings.lr,
                                  weight_decay=settings.weight_decay)
    batches = VerifierBatches(candidates, settings, run.seed)
    training = run.record(settings, device, cache_scenes=int(len(cache.images)),
                          candidate_crops=int(len(candidates.labels)))
    _train(run, device, verifier, optimizer,
           lambda step: verifier_step(verifier, optimizer, batches, device), settings.lr,
           lambda: verifier_validation(verifier, batches, device), 'detector', training,
           real=None if real_frames is None else lambda: real_frames.figures(cascade),
           exported=cascade,
           base=cascade.metadata['training'])
    return cascade
