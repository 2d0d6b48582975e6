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
Trained networks prepared for inference, run by one of two backends.

* 'onnxruntime' (the default): the prepared network is exported to ONNX in memory at load
  (nothing is written) and run by ONNX Runtime's CPU kernels, which run these small
  convolutional networks faster than eager PyTorch on the CPU.
* 'torch': eager PyTorch under ``inference_mode``; the one for a CUDA device.

Both are called the same way, so that the estimators do not depend on the backend: numpy
inputs, the first one the (N, H, W, 3) uint8 RGB images (crops or frame) as they are (the
conversion to the networks' float input runs inside them, see ``nets.images``), and torch
tensors out.
"""

from collections.abc import Sequence
import copy
import io
import warnings

import numpy as np
import torch
from torch import nn
from torch.nn.utils.fusion import fuse_conv_bn_eval

from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.nets.images import ImageInput


def inference_network(network: nn.Module, device: str | torch.device) -> nn.Module:
    """
    Return a copy of an eval-mode network prepared for fast inference on ``device``.

    Each Conv2d directly followed by a BatchNorm2d inside an nn.Sequential is folded into one
    Conv2d (the BatchNorm becomes an Identity): the same function up to float rounding,
    without a separate normalisation pass over every feature map. The copy uses the
    channels_last memory layout, which oneDNN convolutions run faster on. The architecture
    and the weights given are left untouched.
    """
    network = copy.deepcopy(network).eval()
    for sequence in [m for m in network.modules() if isinstance(m, nn.Sequential)]:
        for k in range(len(sequence) - 1):
            conv, norm = sequence[k], sequence[k + 1]
            if isinstance(conv, nn.Conv2d) and isinstance(norm, nn.BatchNorm2d):
                sequence[k], sequence[k + 1] = fuse_conv_bn_eval(conv, norm), nn.Identity()
    return network.to(device).to(memory_format=torch.channels_last)


class TorchRunner:
    """
    Eager PyTorch: ``runner(images, *rest)`` returns the network's outputs.

    Args:
        network: the trained network (a prepared copy runs, ``inference_network``).
        device: the torch device it runs on (the setting ``device``).

    """

    def __init__(self, network: nn.Module, device: str | torch.device) -> None:
        self.network = ImageInput(inference_network(network, device))
        self.device = device

    def __call__(self, *inputs: np.ndarray) -> torch.Tensor | tuple[torch.Tensor, ...]:
        """Run the network on numpy inputs (uint8 images first) on the runner's device."""
        with torch.inference_mode():
            return self.network(*[torch.from_numpy(x).to(self.device) for x in inputs])


def export_module(module: nn.Module, example: Sequence[torch.Tensor],
                  input_names: Sequence[str], output_names: Sequence[str],
                  dynamic_batch: bool = False, opset_version: int | None = None) -> bytes:
    """
    Export an eval-mode module to ONNX, in memory, traced once with ``example`` tensors.

    Args:
        module: its forward has no data-dependent control flow.
        example: the forward's inputs.
        input_names, output_names: the graph's names, in the forward's order.
        dynamic_batch: whether the first axis of every input and output may vary.
        opset_version: the ONNX opset (None: the exporter's default), e.g. to match a graph
            the export is merged with.

    Returns:
        The serialised ONNX model.

    """
    names = list(input_names) + list(output_names)
    batch_axes = {name: {0: 'batch'} for name in names} if dynamic_batch else None
    model = io.BytesIO()
    with warnings.catch_warnings():
        # The TorchScript-based exporter (dynamo=False): the newer torch.export one is far
        # slower to export, too slow for a node's start.
        warnings.simplefilter('ignore')
        torch.onnx.export(module, tuple(example), model, input_names=list(input_names),
                          output_names=list(output_names), dynamic_axes=batch_axes,
                          opset_version=opset_version, dynamo=False)
    return model.getvalue()


def export_onnx(network: nn.Module, example_inputs: Sequence[np.ndarray],
                input_names: Sequence[str], output_names: Sequence[str],
                dynamic_batch: bool = False) -> bytes:
    """
    Export ``ImageInput(inference_network(network, 'cpu'))`` to ONNX, in memory.

    The graph is traced on the CPU (ONNX Runtime runs it there) by ``export_module``.

    Args:
        network: an eval-mode network whose forward has no data-dependent control flow (it
            is traced once with ``example_inputs``).
        example_inputs: tuple of numpy arrays: (N, H, W, 3) uint8 images, then the forward's
            other inputs.
        input_names, output_names: the graph's names, in the forward's order.
        dynamic_batch: whether the first axis of every input and output may vary.

    Returns:
        The serialised ONNX model.

    """
    return export_module(ImageInput(inference_network(network, 'cpu')),
                         [torch.from_numpy(x) for x in example_inputs], input_names,
                         output_names, dynamic_batch)


class OnnxRuntimeRunner:
    """
    ONNX Runtime on the CPU: ``runner(images, *rest)`` returns the network's outputs.

    Args:
        model: a serialised ONNX model (``export_onnx``, or an int8 graph), its inputs in
            the order the runner is called with.
        inference_threads: ONNX Runtime intra-op threads (the setting; 0: one per physical
            core).

    """

    def __init__(self, model: bytes, inference_threads: int) -> None:
        import onnxruntime

        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = inference_threads
        options.inter_op_num_threads = 1
        # Idle threads sleep instead of spinning: the node waits for frames most of the time.
        options.add_session_config_entry('session.intra_op.allow_spinning', '0')
        self._session = onnxruntime.InferenceSession(
            model, options, providers=['CPUExecutionProvider'])
        self._inputs = [node.name for node in self._session.get_inputs()]
        self._single = len(self._session.get_outputs()) == 1

    @classmethod
    def from_network(cls, network: nn.Module, example_inputs: Sequence[np.ndarray],
                     inference_threads: int,
                     dynamic_batch: bool = False) -> 'OnnxRuntimeRunner':
        """Export ``network`` (``export_onnx``, traced with ``example_inputs``) and run it."""
        with torch.inference_mode():
            outputs = ImageInput(network.eval())(*map(torch.from_numpy, example_inputs))
        count = 1 if isinstance(outputs, torch.Tensor) else len(outputs)
        model = export_onnx(network, example_inputs,
                            [f'input{k}' for k in range(len(example_inputs))],
                            [f'output{k}' for k in range(count)], dynamic_batch)
        return cls(model, inference_threads)

    def __call__(self, *inputs: np.ndarray) -> torch.Tensor | tuple[torch.Tensor, ...]:
        """Run the network on numpy inputs (uint8 images first); outputs are torch tensors."""
        feed = dict(zip(self._inputs, inputs))
        outputs = [torch.from_numpy(y) for y in self._session.run(None, feed)]
        return outputs[0] if self._single else tuple(outputs)


def make_runner(network: nn.Module, example_inputs: Sequence[np.ndarray],
                options: PipelineOptions,
                dynamic_batch: bool = False) -> TorchRunner | OnnxRuntimeRunner:
    """
    Prepare ``network`` (eval mode) for inference as ``options`` say.

    The options' ``inference_backend`` runs it, on ``device`` (torch) or with
    ``inference_threads`` intra-op threads (ONNX Runtime; torch's are set for the process
    by ``use_inference_threads``); PipelineOptions has checked that they go together.

    Args:
        network: the trained network.
        example_inputs: tuple of numpy arrays, (N, H, W, 3) uint8 images then the forward's
            other inputs (traced by 'onnxruntime').
        options: the PipelineOptions.
        dynamic_batch: whether the batch size may differ from ``example_inputs``'.

    """
    if options.inference_backend == 'torch':
        return TorchRunner(network, options.device)
    return OnnxRuntimeRunner.from_network(network, example_inputs, options.inference_threads,
                                          dynamic_batch)


def graph_runner(model: bytes, options: PipelineOptions) -> OnnxRuntimeRunner:
    """Run a serialised ONNX graph (an int8 graph) on ONNX Runtime, ``inference_threads``."""
    return OnnxRuntimeRunner(model, options.inference_threads)


def use_inference_threads(options: PipelineOptions) -> None:
    """Set torch's intra-op threads of the process to ``inference_threads`` (0: leave them)."""
    if options.inference_threads:
        torch.set_num_threads(options.inference_threads)
