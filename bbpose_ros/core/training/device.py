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
Where a training run computes: the CPU, or a CUDA GPU with automatic mixed precision.

Batches are drawn on the CPU (numpy and a CPU generator, so a seed gives the same batches
on either device) and moved to the device for the step. On CUDA the networks' forward pass
runs under ``torch.autocast`` (float16 where PyTorch deems it safe) and a
``torch.amp.GradScaler`` scales the loss so that small float16 gradients do not vanish;
the losses themselves are computed in float32 (a Dot Product Loss near 0 needs quaternion
dot products near 1 resolved finer than float16's 5e-4 steps there, the focal loss
log-probabilities near 0 and 1). On the CPU everything stays float32.

Checkpoints hold CPU tensors only (``cpu_copy``) and load with ``map_location='cpu'``, so a
run checkpointed on one device resumes on the other; the weight files were already
device-free.
"""

from collections.abc import Callable
from typing import Any

import torch

from bbpose_ros.core.util.errors import InputError

DEVICES = ('cpu', 'cuda')


def training_device(name: str | None) -> torch.device:
    """
    Resolve ``--device``: 'cpu', 'cuda', or None for cuda when torch sees a GPU, else cpu.

    Raises:
        InputError: 'cuda' without a CUDA GPU visible to torch, or an unknown name.

    """
    if name is None:
        return torch.device('cuda' if torch.cuda.is_available() else 'cpu')
    if name not in DEVICES:
        raise InputError(f'unknown training device "{name}"; choose one of {", ".join(DEVICES)}')
    if name == 'cuda' and not torch.cuda.is_available():
        build = (f'torch {torch.__version__} has no CUDA support' if torch.version.cuda is None
                 else f'torch {torch.__version__} (CUDA {torch.version.cuda}) finds no GPU')
        raise InputError(f'training device cuda is not available: {build}; train with '
                         '--device cpu')
    return torch.device(name)


class TrainingDevice:
    """
    Runs the steps of a training run on one device (see the module docstring).

    Args:
        device: 'cpu', 'cuda' or a torch.device.
        mixed_precision: use autocast and loss scaling on CUDA (ignored on the CPU).

    """

    def __init__(self, device: str | torch.device = 'cpu',
                 mixed_precision: bool = True) -> None:
        self.device = torch.device(device)
        self.mixed = mixed_precision and self.device.type == 'cuda'
        self.scaler = torch.amp.GradScaler('cuda') if self.mixed else None
        if self.device.type == 'cuda':
            # Batch shapes repeat step after step: let cuDNN time its convolution
            # algorithms once per shape and keep the fastest.
            torch.backends.cudnn.benchmark = True

    def __str__(self) -> str:
        if self.device.type != 'cuda':
            return str(self.device)
        precision = 'automatic mixed precision' if self.mixed else 'float32'
        return f'{self.device} ({torch.cuda.get_device_name(self.device)}, {precision})'

    def put(self, *tensors: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """Move tensors to the device (images keep their channels_last layout)."""
        return tuple(t.to(self.device, non_blocking=True) for t in tensors)

    def forward(self, function: Callable[..., Any], *inputs: torch.Tensor) -> Any:
        """
        Run ``function(*inputs)``, a network's forward pass, under autocast on CUDA.

        Returns its tensor (or tuple of tensors) in float32, ready for a float32 loss.
        """
        if not self.mixed:
            return function(*inputs)
        with torch.autocast(device_type='cuda', dtype=torch.float16):
            outputs = function(*inputs)
        if isinstance(outputs, torch.Tensor):
            return outputs.float()
        return tuple(x.float() for x in outputs)

    def minimise(self, optimizer: torch.optim.Optimizer, loss: torch.Tensor) -> float:
        """One optimiser step on the scalar ``loss`` (scaled on CUDA); returns the loss."""
        optimizer.zero_grad(set_to_none=True)
        if self.scaler is None:
            loss.backward()
            optimizer.step()
        else:
            self.scaler.scale(loss).backward()
            self.scaler.step(optimizer)     # skipped when the gradients overflowed
            self.scaler.update()
        return float(loss.detach())

    def state_dict(self) -> dict[str, Any]:
        """Return the loss scaler's state for a checkpoint (empty without one)."""
        return {} if self.scaler is None else self.scaler.state_dict()

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore a checkpoint's loss scale (a CPU checkpoint has none: a fresh scaler)."""
        if self.scaler is not None and state:
            self.scaler.load_state_dict(state)


def cpu_copy(value: Any) -> Any:
    """Copy the tensors of a nested dict / list / tuple to the CPU (other values as they are)."""
    if isinstance(value, torch.Tensor):
        return value.detach().cpu()
    if isinstance(value, dict):
        return {k: cpu_copy(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(cpu_copy(v) for v in value)
    return value
