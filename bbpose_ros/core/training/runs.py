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
Training runs of Q-Net and the detector: build, train, checkpoint, export weight files.

Each run folder gets ``checkpoint.pt`` (resumable), ``log.csv``, ``train.log``, ``loss.png``
and the exported weight file (``qnet.pt`` / ``detector.pt``, with metadata, see
``core.weights``), re-exported at every checkpoint; ``export`` copies it elsewhere too.
"""

from dataclasses import asdict
from pathlib import Path
import shutil
import subprocess
import sys

import torch

from bbpose_ros.core.nets.detector import CenterBoxNet
from bbpose_ros.core.nets.qnet import QNet
from bbpose_ros.core.training.detector_training import (detector_step, detector_validation,
                                                        DetectorBatches)
from bbpose_ros.core.training.loop import run_loop, RunLog
from bbpose_ros.core.training.qnet_training import qnet_step, qnet_validation, QNetBatches
from bbpose_ros.core.weights import save_weights


def git_commit():
    """Commit hash of the working tree's HEAD, or 'unknown' outside a git checkout."""
    try:
        return subprocess.run(['git', 'rev-parse', 'HEAD'], capture_output=True, text=True,
                              check=True, cwd=Path(__file__).parent).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return 'unknown'


def _prepare(run_dir, seed, threads):
    torch.manual_seed(seed)
    if threads:
        torch.set_num_threads(threads)
    log = RunLog(run_dir)
    log.text(f'command: {" ".join(sys.argv)} (torch threads {torch.get_num_threads()})')
    return log


def _exporter(run_dir, network, kind, training, export, validation):
    """Return a checkpoint hook that writes the weight file (and its copy)."""
    def export_weights(step):
        record = dict(training, steps=step, validation=validation)
        path = Path(run_dir) / f'{kind}.pt'
        save_weights(path, network, kind, record)
        if export:
            Path(export).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(path, export)
    return export_weights


def _validated(validate, store):
    """Wrap ``validate`` so that its latest figures are kept in ``store``."""
    def run():
        figures = validate()
        store.clear()
        store.update(figures)
        return figures
    return run


def train_qnet(cache, models, config, settings, run_dir, steps, seconds=None, seed=0,
               threads=None, export=None, every=500, progress=True, real_crops=None):
    """
    Train (or resume) a Q-Net on a TrainingCache or CropCache; returns the network.

    ``config`` is a QNetConfig, ``settings`` a QNetTrainSettings; budgets as in
    ``loop.run_loop``. The weight file is written to ``run_dir/qnet.pt`` (and ``export``).
    ``real_crops`` (a ``RealCrops``) adds real-frame figures to every validation.
    """
    _prepare(run_dir, seed, threads)
    network = QNet(config).to(memory_format=torch.channels_last)
    optimizer = torch.optim.AdamW(network.parameters(), settings.lr,
                                  weight_decay=settings.weight_decay)
    batches = QNetBatches(cache, config, models, settings, seed)
    validation = {}
    training = {'command': ' '.join(sys.argv), 'git_commit': git_commit(), 'seed': seed,
                'settings': asdict(settings), 'total_steps': steps,
                'cache_objects': cache.objects, 'cache_instances': int(len(cache.visib))}
    run_loop(run_dir, network, optimizer, lambda step: qnet_step(network, optimizer, batches),
             steps, seconds, settings.lr,
             validate=_validated(lambda: _qnet_figures(network, batches, real_crops),
                                 validation),
             every=every, on_checkpoint=_exporter(run_dir, network, 'qnet', training, export,
                                                  validation),
             progress=progress)
    return network


def _qnet_figures(network, batches, real_crops):
    figures = qnet_validation(network, batches)
    if real_crops is not None:
        figures.update(real_crops.figures(network))
    return figures


def train_detector(cache, config, settings, run_dir, steps, seconds=None, seed=0,
                   threads=None, export=None, every=500, progress=True):
    """Train (or resume) the detector on a TrainingCache; as ``train_qnet`` otherwise."""
    _prepare(run_dir, seed, threads)
    network = CenterBoxNet(config).to(memory_format=torch.channels_last)
    optimizer = torch.optim.AdamW(network.parameters(), settings.lr,
                                  weight_decay=settings.weight_decay)
    batches = DetectorBatches(cache, config, settings, seed)
    validation = {}
    training = {'command': ' '.join(sys.argv), 'git_commit': git_commit(), 'seed': seed,
                'settings': asdict(settings), 'total_steps': steps,
                'cache_scenes': int(len(cache.images))}
    run_loop(run_dir, network, optimizer,
             lambda step: detector_step(network, optimizer, batches), steps, seconds,
             settings.lr,
             validate=_validated(lambda: detector_validation(network, batches), validation),
             every=every, on_checkpoint=_exporter(run_dir, network, 'detector', training,
                                                  export, validation),
             progress=progress)
    return network
