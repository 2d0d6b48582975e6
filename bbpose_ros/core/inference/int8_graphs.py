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
Int8 graphs of the detector and Q-Net: their networks with 8-bit weights and activations.

ONNX Runtime's static quantisation (``training.quantization`` makes the files) turns the
convolutions and fully connected layers into integer ones. A CPU with int8 dot-product
instructions (AVX-512 VNNI, AVX-VNNI) runs those much faster than float ones; an AVX2 CPU
without them still runs the whole frame faster, at the same accuracy on the held-out
frames (docs/performance.md). ``precision: auto`` therefore takes the int8 graphs on both
(``INT8_AUTO_FLAGS``, ``choose_int8_graph``) and the float networks elsewhere.

A graph file (``<weights stem>_int8.onnx`` beside the float weight file) holds metadata
naming the float file it was quantised from (its SHA-256): a graph quantised from other
weights is refused. What it computes, by network kind (``INPUT_NAMES`` -> ``OUTPUT_NAMES``):

* 'detector': the (1, H, W, 3) uint8 RGB image -> its (1, C, h, w) heatmap logits and
  (1, 4, h, w) box log-sides. The peak search (``detector.peaks``), whose size depends on
  the node's settings, is added in float at load (``with_peak_search``).
* 'qnet': (N, S, S, 3) uint8 crops and their (N,) int64 object indices -> every
  hypothesis, (N, K, 4) unnormalised wxyz quaternions and (N, K) logits
  (``rotation_estimator.run_network`` with all hypotheses); any batch size.
"""

import hashlib
from pathlib import Path

import torch
from torch import nn

from bbpose_ros.core.inference.backends import export_module
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.nets.detector import DetectorConfig, peaks
from bbpose_ros.core.util.errors import InputError

INT8_FORMAT = '1'
INPUT_NAMES = {'detector': ('images',), 'qnet': ('crops', 'object_index')}
OUTPUT_NAMES = {'detector': ('heatmap_logits', 'box_log'),
                'qnet': ('quaternions_wxyz', 'hypothesis_logits')}
# Instruction-set flags (Linux /proc/cpuinfo) under which ONNX Runtime's int8 kernels use
# integer dot products.
INT8_DOT_FLAGS = ('avx512_vnni', 'avx_vnni', 'amx_int8')
# Flags of the CPUs where 'auto' runs the int8 graphs: those with int8 dot products, and
# AVX2 ones without, where the int8 graphs measured faster than float at the same accuracy
# (docs/performance.md, both classes of CPU).
INT8_AUTO_FLAGS = INT8_DOT_FLAGS + ('avx2',)


def int8_kind(network: str) -> str:
    """Return the metadata ``kind`` of a network's int8 graph ('detector' or 'qnet')."""
    return f'bbpose.{network}_int8'


def int8_graph_path(weights: Path | str) -> Path:
    """Return where the int8 graph of a float weight file lives: ``<stem>_int8.onnx``."""
    path = Path(weights)
    return path.with_name(f'{path.stem}_int8.onnx')


def file_sha256(path: Path | str) -> str:
    """Return the hex SHA-256 of a file's bytes."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def cpu_flags(cpuinfo: str | None = None) -> set[str]:
    """
    Return the CPU's instruction-set flags.

    Args:
        cpuinfo: the text of /proc/cpuinfo (default: read it; no flags where there is none).

    """
    if cpuinfo is None:
        try:
            cpuinfo = Path('/proc/cpuinfo').read_text()
        except OSError:
            return set()
    flags = set()
    for line in cpuinfo.splitlines():
        if line.startswith('flags'):
            flags.update(line.partition(':')[2].split())
    return flags


def cpu_has_int8_dot(cpuinfo: str | None = None) -> bool:
    """Tell whether the CPU has int8 dot-product instructions (``INT8_DOT_FLAGS``)."""
    return bool(cpu_flags(cpuinfo) & set(INT8_DOT_FLAGS))


def int8_pays(cpuinfo: str | None = None) -> bool:
    """Tell whether 'auto' runs the int8 graphs on this CPU (``INT8_AUTO_FLAGS``)."""
    return bool(cpu_flags(cpuinfo) & set(INT8_AUTO_FLAGS))


def read_int8_graph(path: Path | str, weights: Path | str, network: str):
    """
    Read the int8 graph of a ``network`` ('detector', 'qnet') quantised from ``weights``.

    Returns:
        The onnx.ModelProto.

    Raises:
        InputError: the file is missing, is not an ONNX model, is not an int8 graph of this
            network and format, or was quantised from another float weight file.

    """
    import onnx

    path = Path(path)
    if not path.is_file():
        raise InputError(f'int8 {network} graph {path} not found; make it with "bbpose train '
                         f'quantize --network {network} --weights {weights}"')
    try:
        model = onnx.load_from_string(path.read_bytes())
    except Exception as err:   # protobuf raises its own DecodeError
        raise InputError(f'int8 {network} graph {path} is not a readable ONNX model: '
                         f'{err}') from err
    meta = {prop.key: prop.value for prop in model.metadata_props}
    if meta.get('kind') != int8_kind(network) or meta.get('format') != INT8_FORMAT:
        raise InputError(f'{path} is not an int8 {network} graph of format {INT8_FORMAT} '
                         f'(metadata kind "{meta.get("kind")}", format "{meta.get("format")}")')
    if meta.get('source_sha256') != file_sha256(weights):
        raise InputError(f'int8 {network} graph {path}: field source_sha256 does not match '
                         f'{weights} (quantised from other weights); re-run "bbpose train '
                         f'quantize --network {network} --weights {weights}"')
    return model


def choose_int8_graph(options: PipelineOptions, weights: Path | str, network: str):
    """
    Return the int8 graph ``network`` runs under ``options.inference_precision``, or None (float).

    'int8' reads ``int8_graph_path(weights)`` and raises InputError when it is missing or
    made from other weights; 'auto' takes it only with the onnxruntime backend on a CPU where
    it pays (``int8_pays``), and where it is missing or does not fit runs the float network.
    """
    if options.inference_precision == 'fp32' or options.inference_backend != 'onnxruntime':
        return None
    path = int8_graph_path(weights)
    if options.inference_precision == 'int8':
        return read_int8_graph(path, weights, network)
    if not int8_pays():
        return None
    try:
        return read_int8_graph(path, weights, network)
    except InputError:
        return None


class _PeakSearch(nn.Module):
    """``peaks`` of given heatmap logits and box log-sides, as a module to export."""

    def __init__(self, count: int) -> None:
        super().__init__()
        self.count = count

    def forward(self, heatmap_logits: torch.Tensor,
                box_log: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Return ``peaks(heatmap_logits, box_log, count)``."""
        return peaks(heatmap_logits, box_log, self.count)


def with_peak_search(model, config: DetectorConfig, count: int) -> bytes:
    """
    Append the float peak search of ``count`` peaks a class to an int8 heatmap graph.

    Args:
        model: the detector's onnx.ModelProto of ``read_int8_graph``.
        config: the float detector's DetectorConfig (input size, stride, objects).
        count: peaks per class, as ``detector.PeakOutputs``.

    Returns:
        The serialised model: (1, H, W, 3) uint8 image -> ``peaks``' scores, cells, sides.

    """
    import onnx
    from onnx import compose

    width, height = config.input_size
    grid = (height // config.stride, width // config.stride)
    example = (torch.zeros((1, len(config.objects), *grid)), torch.zeros((1, 4, *grid)))
    opset = next(o.version for o in model.opset_import if o.domain in ('', 'ai.onnx'))
    search = onnx.load_from_string(export_module(
        _PeakSearch(count), example, OUTPUT_NAMES['detector'], ('scores', 'cells', 'sides'),
        opset_version=opset))
    search.ir_version = model.ir_version
    search = compose.add_prefix(search, 'peaks/')
    merged = compose.merge_models(model, search,
                                  io_map=[(name, f'peaks/{name}')
                                          for name in OUTPUT_NAMES['detector']])
    return merged.SerializeToString()
