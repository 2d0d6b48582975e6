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
Quantise a trained detector or Q-Net to the int8 graph ``inference.int8_graphs`` runs.

ONNX Runtime's static quantisation: int8 weights per output channel, uint8 activations whose
ranges (min / max) are measured on calibration inputs, in the QOperator format (QLinearConv
nodes: the format whose integer kernels ONNX Runtime runs fastest on the CPU). Calibrate on
renders (a scene cache: its frames for the detector, its instances' crops for Q-Net), never
on evaluation frames.
"""

from contextlib import contextmanager
import logging
import os
from pathlib import Path
import tempfile

import cv2
import numpy as np

from bbpose_ros.core.inference.backends import export_onnx
from bbpose_ros.core.inference.int8_graphs import (file_sha256, INPUT_NAMES, INT8_FORMAT,
                                                   int8_graph_path, int8_kind, OUTPUT_NAMES)
from bbpose_ros.core.inference.weights import load_network
from bbpose_ros.core.pipeline.rotation_estimator import run_network
from bbpose_ros.core.util.errors import InputError

# Q-Net calibration crops: boxes jittered as a detector's (per-side error / box size, as
# Q-Net trains), fed in batches of this size.
CROP_BOX_SIGMA = 0.05
CROP_BATCH = 16
# Q-Net calibration crops a folder's int8 graph is calibrated on (``write_int8_graphs``).
CALIBRATION_CROPS = 256


def calibration_images(frames: np.ndarray, input_size: tuple[int, int],
                       count: int) -> np.ndarray:
    """
    Resize the first ``count`` frames to the detector's input as ``BoxDetector`` does.

    Args:
        frames: (S, H, W, 3) uint8 RGB images (a scene cache's ``images``).
        input_size: (width, height) of the detector's input.
        count: how many.

    Returns:
        (min(count, S), height, width, 3) uint8.

    """
    return np.stack([cv2.resize(frame, tuple(input_size), interpolation=cv2.INTER_AREA)
                     for frame in frames[:count]])


def calibration_crops(cache, config, count: int,
                      seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """
    Make Q-Net's calibration inputs: crops of ``count`` instances at least 30 % visible.

    Args:
        cache: a ``training.cache.TrainingCache``.
        config: Q-Net's QNetConfig (objects, crop size, context).
        count: instances (at most those of Q-Net's objects in the cache).
        seed: which instances, and the box jitter.

    Returns:
        (n, S, S, 3) uint8 crops and their (n,) int64 indices into ``config.objects``.

    """
    index = {name: k for k, name in enumerate(config.objects)}
    known = np.array([index.get(name, -1) for name in cache.objects])[cache.object]
    rng = np.random.default_rng(seed)
    chosen = np.flatnonzero((cache.visib >= 0.3) & (known >= 0))
    ids = rng.choice(chosen, min(count, len(chosen)), replace=False)
    crops, _ = cache.input_crops(ids, rng, CROP_BOX_SIGMA, config.crop_size, config.context)
    return crops, known[ids].astype(np.int64)


def quantize_network(weights: Path | str, network_kind: str,
                     inputs: tuple[np.ndarray, ...], out: Path | str,
                     command: str = '') -> Path:
    """
    Write the int8 graph of a float weight file, calibrated on ``inputs``.

    Args:
        weights: the float weight file (.pt).
        network_kind: 'detector' or 'qnet'.
        inputs: the calibration inputs as the graph takes them (``int8_graphs``): for the
            detector ((N, H, W, 3) uint8 images at its input size,), for Q-Net ((N, S, S, 3)
            uint8 crops, (N,) int64 object indices of the file's ``objects``).
        out: the .onnx file to write (replaced whole: written beside it, then renamed).
        command: the command line that made it, kept in the file's metadata.

    Returns:
        ``out`` as a Path.

    Raises:
        InputError: unreadable weights, or inputs of the wrong shape.

    """
    from onnxruntime.quantization import (CalibrationDataReader, CalibrationMethod,
                                          QuantFormat, quantize_static, QuantType)
    from onnxruntime.quantization.shape_inference import quant_pre_process
    import onnx

    network = load_network(weights, network_kind)
    _check_inputs(network, network_kind, inputs)
    names = INPUT_NAMES[network_kind]
    batch = 1 if network_kind == 'detector' else CROP_BATCH
    if network_kind == 'qnet':
        network = run_network(network, all_hypotheses=True)

    class Reader(CalibrationDataReader):
        def __init__(self):
            self.start = 0

        def get_next(self):
            if self.start >= len(inputs[0]):
                return None
            self.start += batch
            return {name: x[self.start - batch:self.start] for name, x in zip(names, inputs)}

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as folder:
        float_path, prepared_path = Path(folder, 'float.onnx'), Path(folder, 'prepared.onnx')
        float_path.write_bytes(export_onnx(network, tuple(x[:1] for x in inputs), names,
                                           OUTPUT_NAMES[network_kind],
                                           dynamic_batch=network_kind == 'qnet'))
        quant_pre_process(str(float_path), str(prepared_path))
        int8_path = Path(folder, 'int8.onnx')
        with _root_log_level(logging.ERROR):
            # It warns, with the whole type, that the uint8 and int64 inputs are not quantised.
            # 7-bit weights (reduce_range): x86 CPUs without VNNI multiply u8 x s8 pairs into
            # saturating int16 sums (VPMADDUBSW), which full-range weights overflow.
            quantize_static(str(prepared_path), str(int8_path), Reader(),
                            quant_format=QuantFormat.QOperator, per_channel=True,
                            reduce_range=True, activation_type=QuantType.QUInt8,
                            weight_type=QuantType.QInt8,
                            calibrate_method=CalibrationMethod.MinMax)
        model = onnx.load(str(int8_path))
    meta = {'kind': int8_kind(network_kind), 'format': INT8_FORMAT,
            'source_sha256': file_sha256(weights), 'source_file': Path(weights).name,
            'calibration_inputs': str(len(inputs[0])), 'command': command}
    del model.metadata_props[:]
    for key, value in meta.items():
        model.metadata_props.add(key=key, value=value)
    partial = out.with_name(out.name + '.partial')
    partial.write_bytes(model.SerializeToString())
    os.replace(partial, out)
    return out


def write_int8_graphs(folder: Path | str, cache, frames: int, seed: int,
                      command: str = '') -> None:
    """
    Write a folder's ``detector_int8.onnx`` and ``qnet_int8.onnx`` from its float weights.

    The outputs of ``bbpose add-object`` and ``bbpose adapt`` alike: ``folder`` holds
    ``detector.pt`` and ``qnet.pt``; the detector is calibrated on the first ``frames``
    images of ``cache`` (a ``training.cache.TrainingCache`` at the detector's input size),
    Q-Net on ``CALIBRATION_CROPS`` crops of its instances drawn with ``seed``.
    """
    folder = Path(folder)
    images = calibration_images(cache.images, cache.input_size, frames)
    quantize_network(folder / 'detector.pt', 'detector', (images,),
                     int8_graph_path(folder / 'detector.pt'), command)
    qnet = load_network(folder / 'qnet.pt', 'qnet')
    crops = calibration_crops(cache, qnet.config, CALIBRATION_CROPS, seed)
    quantize_network(folder / 'qnet.pt', 'qnet', crops, int8_graph_path(folder / 'qnet.pt'),
                     command)


def _check_inputs(network, network_kind, inputs):
    """Raise InputError unless ``inputs`` are what the network's graph takes."""
    if network_kind == 'detector':
        width, height = network.config.input_size
        expected = [((height, width, 3), np.uint8)]
    else:
        size = network.config.crop_size
        expected = [((size, size, 3), np.uint8), ((), np.int64)]
    shapes = [(x.shape[1:], x.dtype) for x in inputs]
    if len(inputs) != len(expected) or any(
            shape != want or dtype != want_dtype
            for (shape, dtype), (want, want_dtype) in zip(shapes, expected)) \
            or len({len(x) for x in inputs}) != 1 or not len(inputs[0]):
        raise InputError(f'calibration inputs of the {network_kind} must be (N, *shape) '
                         f'{expected}, got {[(x.shape, x.dtype) for x in inputs]}')


@contextmanager
def _root_log_level(level):
    """Raise the root logger's level (the quantiser logs there) for a block."""
    root = logging.getLogger()
    previous = root.level
    root.setLevel(level)
    try:
        yield
    finally:
        root.setLevel(previous)
