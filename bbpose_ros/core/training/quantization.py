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
Quantise a trained detector to the int8 graph ``pipeline.int8_detector`` runs.

ONNX Runtime's static quantisation: int8 weights per output channel, uint8 activations whose
ranges (min / max) are measured on calibration images, in the QOperator format (QLinearConv
nodes: the format whose integer kernels ONNX Runtime runs fastest on the CPU). Calibrate on
renders (a scene cache), never on evaluation frames.
"""

from contextlib import contextmanager
import logging
import os
from pathlib import Path
import tempfile

import cv2
import numpy as np

from bbpose_ros.core.errors import InputError
from bbpose_ros.core.pipeline.backends import export_onnx
from bbpose_ros.core.pipeline.int8_detector import (file_sha256, INPUT_NAME, INT8_FORMAT,
                                                    INT8_KIND, OUTPUT_NAMES)
from bbpose_ros.core.pipeline.weights import load_network


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


def quantize_detector(weights: Path | str, images: np.ndarray, out: Path | str,
                      command: str = '') -> Path:
    """
    Write the int8 graph of a float detector file, calibrated on ``images``.

    Args:
        weights: the float detector weight file (.pt).
        images: (N, H, W, 3) uint8 RGB calibration images at the detector's input size.
        out: the .onnx file to write (replaced whole: written beside it, then renamed).
        command: the command line that made it, kept in the file's metadata.

    Returns:
        ``out`` as a Path.

    Raises:
        InputError: unreadable weights, or images not at the detector's input size.

    """
    from onnxruntime.quantization import (CalibrationDataReader, CalibrationMethod,
                                          QuantFormat, quantize_static, QuantType)
    from onnxruntime.quantization.shape_inference import quant_pre_process
    import onnx

    network = load_network(weights, 'detector')
    width, height = network.config.input_size
    if images.ndim != 4 or images.shape[1:] != (height, width, 3) or images.dtype != np.uint8:
        raise InputError(f'calibration images must be (N, {height}, {width}, 3) uint8, got '
                         f'{images.shape} {images.dtype}')

    class Reader(CalibrationDataReader):
        def __init__(self):
            self.images = iter(images)

        def get_next(self):
            image = next(self.images, None)
            return None if image is None else {INPUT_NAME: image[None]}

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as folder:
        float_path, prepared_path = Path(folder, 'float.onnx'), Path(folder, 'prepared.onnx')
        float_path.write_bytes(export_onnx(network, (images[:1],), [INPUT_NAME], OUTPUT_NAMES))
        quant_pre_process(str(float_path), str(prepared_path))
        int8_path = Path(folder, 'int8.onnx')
        with _root_log_level(logging.ERROR):
            # It warns, with the whole type, that the uint8 image input is not quantised.
            quantize_static(str(prepared_path), str(int8_path), Reader(),
                            quant_format=QuantFormat.QOperator, per_channel=True,
                            activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8,
                            calibrate_method=CalibrationMethod.MinMax)
        model = onnx.load(str(int8_path))
    meta = {'kind': INT8_KIND, 'format': INT8_FORMAT, 'source_sha256': file_sha256(weights),
            'source_file': Path(weights).name, 'input_size': f'{width},{height}',
            'calibration_images': str(len(images)), 'command': command}
    del model.metadata_props[:]
    for key, value in meta.items():
        model.metadata_props.add(key=key, value=value)
    partial = out.with_name(out.name + '.partial')
    partial.write_bytes(model.SerializeToString())
    os.replace(partial, out)
    return out


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
