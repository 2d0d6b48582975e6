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
The shared training loop: step or time budget, checkpoints and resume, log and loss plot.

A run folder holds ``checkpoint.pt`` (network, optimizer, step, loss scale; CPU tensors, so
it resumes on either device),
``log.csv`` (step, seconds, loss, lr and validation figures), ``train.log`` (text) and
``loss.png``. Resuming continues the step count, the learning-rate schedule and the log.
"""

from collections.abc import Callable, Mapping, Sequence
import csv
import math
from pathlib import Path
import time
from typing import Any

from matplotlib.figure import Figure
import torch
from torch import nn
from tqdm import tqdm

from bbpose_ros.core.training.device import cpu_copy, TrainingDevice
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.core.util.files import atomic_output


class RunLog:
    """Appends rows to ``log.csv`` and lines to ``train.log`` in a run folder."""

    def __init__(self, run_dir: Path | str) -> None:
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.csv_path = self.run_dir / 'log.csv'
        self.text_path = self.run_dir / 'train.log'

    def text(self, line: str) -> None:
        """Write one timestamped line to train.log (and tqdm's stream)."""
        stamp = time.strftime('%Y-%m-%d %H:%M:%S')
        with open(self.text_path, 'a') as stream:
            stream.write(f'{stamp} {line}\n')
        tqdm.write(line)

    def row(self, values: Mapping[str, Any]) -> None:
        """Append the dict ``values`` as a CSV row; the first row also writes the header."""
        new = not self.csv_path.is_file()
        with open(self.csv_path, 'a', newline='') as stream:
            writer = csv.DictWriter(stream, fieldnames=list(values))
            if new:
                writer.writeheader()
            writer.writerow(values)

    def rows(self) -> list[dict[str, float]]:
        """All CSV rows as dicts of floats (empty cells become NaN)."""
        if not self.csv_path.is_file():
            return []
        with open(self.csv_path) as stream:
            return [{k: float(v) if v not in ('', None) else math.nan for k, v in r.items()}
                    for r in csv.DictReader(stream)]


def plot_curves(path: Path | str,
                series: Mapping[str, tuple[Sequence[float], Sequence[float]]], title: str,
                ylabel: str = 'loss', log_y: bool = False,
                ylim: tuple[float, float] | None = None) -> None:
    """Plot {label: (steps, values)} into a PNG at ``path`` (``ylim``: (low, high) or None)."""
    figure = Figure(figsize=(6, 4))
    axes = figure.add_subplot()
    for label, (steps, values) in series.items():
        axes.plot(steps, values, label=label)
    axes.set_xlabel('iteration')
    axes.set_ylabel(ylabel)
    axes.set_title(title)
    if log_y:
        axes.set_yscale('log')
    if ylim:
        axes.set_ylim(*ylim)
    axes.grid(alpha=0.3)
    axes.legend()
    figure.tight_layout()
    figure.savefig(path, dpi=100)


def cosine_lr(base_lr: float, step: int, total_steps: int, warmup: int = 200) -> float:
    """Linear warm-up then cosine decay to 5 % of ``base_lr``."""
    if step < warmup:
        return base_lr * (step + 1) / warmup
    progress = min(1.0, (step - warmup) / max(1, total_steps - warmup))
    return base_lr * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * progress)))


def run_loop(run_dir: Path | str, network: nn.Module, optimizer: torch.optim.Optimizer,
             train_step: Callable[[int], float], steps: int, seconds: float | None,
             base_lr: float, validate: Callable[[], Mapping[str, float]] | None = None,
             every: int = 500, on_checkpoint: Callable[[int], None] | None = None,
             progress: bool = True, extra_state: dict[str, Any] | None = None,
             device: TrainingDevice | None = None) -> int:
    """
    Train until ``steps`` total steps or ``seconds`` of this call, whichever is first.

    Args:
        run_dir: run folder (checkpoint.pt there is resumed).
        network: the torch module.
        optimizer: its optimizer.
        train_step: callable(step) -> loss float; does one optimisation step.
        steps: total step budget (the cosine schedule spans it).
        seconds: wall-clock budget of this call (None: unlimited).
        base_lr: peak learning rate.
        validate: optional callable() -> dict of validation figures, run at checkpoints.
        every: steps between checkpoints.
        on_checkpoint: optional callable(step) after each checkpoint (e.g. export weights),
            and once when a finished run is called again.
        progress: show a tqdm bar.
        extra_state: dict saved in and restored from the checkpoint (updated in place).
        device: the TrainingDevice ``train_step`` uses; its loss scale is checkpointed.

    Returns:
        The number of steps done in total.

    """
    log = RunLog(run_dir)
    checkpoint = Path(run_dir) / 'checkpoint.pt'
    step = 0
    if checkpoint.is_file():
        state = torch.load(checkpoint, map_location='cpu', weights_only=True)
        network.load_state_dict(state['network'])
        scales = [group.get('lr_scale', 1.0) for group in optimizer.param_groups]
        try:
            optimizer.load_state_dict(state['optimizer'])
        except ValueError as err:
            raise InputError(f'{checkpoint} was trained with other optimizer groups '
                             f'(e.g. a frozen vs a fine-tuned trunk): {err}') from None
        for group, scale in zip(optimizer.param_groups, scales):
            group['lr_scale'] = scale       # this call's settings, not the checkpoint's
        step = int(state['step'])
        if device is not None:
            device.load_state_dict(state.get('grad_scaler', {}))
        if extra_state is not None:
            extra_state.update(state.get('extra', {}))
        log.text(f'resumed from {checkpoint} at step {step}')
    start = time.monotonic()
    losses = []
    bar = tqdm(total=steps, initial=step, desc='training', unit='step', disable=not progress)
    while step < steps and (seconds is None or time.monotonic() - start < seconds):
        lr = cosine_lr(base_lr, step, steps)
        for group in optimizer.param_groups:
            group['lr'] = lr * group.get('lr_scale', 1.0)
        network.train()
        losses.append(train_step(step))
        step += 1
        bar.update()
        bar.set_postfix(loss=f'{losses[-1]:.4f}')
        if step % every == 0 or step == steps:
            _checkpoint(checkpoint, network, optimizer, step, extra_state, device)
            figures = validate() if validate else {}
            mean = sum(losses[-every:]) / len(losses[-every:])
            log.row({'step': step, 'seconds': round(time.monotonic() - start, 1),
                     'loss': mean, 'lr': lr, **figures})
            log.text(f'step {step} loss {mean:.5f} lr {lr:.2e} ' +
                     ' '.join(f'{k} {v:.4f}' for k, v in figures.items()))
            _plot_log(log)
            if on_checkpoint:
                on_checkpoint(step)
    bar.close()
    if not losses and on_checkpoint:
        # A finished run called again re-exports its weights (e.g. to a new --export).
        if validate:
            validate()
        on_checkpoint(step)
    elif step % every:
        _checkpoint(checkpoint, network, optimizer, step, extra_state, device)
        if on_checkpoint:
            on_checkpoint(step)
    return step


def _checkpoint(path, network, optimizer, step, extra_state, device):
    state = {'network': network.state_dict(), 'optimizer': optimizer.state_dict(),
             'step': step, 'extra': extra_state or {},
             'grad_scaler': device.state_dict() if device is not None else {}}
    with atomic_output(path) as tmp:
        torch.save(cpu_copy(state), tmp)


def _plot_log(log):
    rows = log.rows()
    steps = [r['step'] for r in rows]
    series = {'train loss': (steps, [r['loss'] for r in rows])}
    if rows and 'val_loss' in rows[0]:
        series['validation loss'] = (steps, [r['val_loss'] for r in rows])
    plot_curves(log.run_dir / 'loss.png', series, log.run_dir.name, log_y=True)
    if rows:
        plot_sim_to_real(log.run_dir, rows)


def plot_sim_to_real(run_dir: Path | str, rows: Sequence[Mapping[str, float]]) -> None:
    """
    Chart each figure measured on both held-out renders (val_X) and real frames (real_X).

    Written as ``sim_to_real.png`` when the log has such pairs (Q-Net's ``--real-val``:
    median rotation error and acc15), in degrees when the pairs are, else as fractions.
    """
    pairs = [key[len('real_'):] for key in rows[0]
             if key.startswith('real_') and 'val_' + key[len('real_'):] in rows[0]]
    if not pairs:
        return
    degrees = any(name.endswith('_deg') for name in pairs)
    steps = [r['step'] for r in rows]
    series = {f'{side} {name}': (steps, [r[f'{prefix}{name}'] for r in rows])
              for name in pairs if name.endswith('_deg') == degrees
              for side, prefix in (('synthetic', 'val_'), ('real', 'real_'))}
    plot_curves(Path(run_dir) / 'sim_to_real.png', series,
                f'{Path(run_dir).name}: held-out renders vs real frames',
                ylabel='degrees' if degrees else 'fraction')
