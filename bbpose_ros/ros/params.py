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
The parameters of ``bbpose_node``: declarations with descriptors, and their validation.

Read-only parameters need a restart to change (they shape the pipeline, the topics or the
QoS); the others (``sync_slop``, ``rectified``, ``publish_debug_image``) are read on every
frame and may be set at run time. ``config/bbpose.yaml`` documents each one.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
import os
from pathlib import Path
from typing import Any, TYPE_CHECKING

from ament_index_python.packages import get_package_share_directory
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.qos import QoSProfile, QoSReliabilityPolicy
import yaml

from bbpose_ros.core.data.bop import DEFAULT_DATASET
from bbpose_ros.core.errors import InputError
from bbpose_ros.core.pipeline.backends import BACKENDS
from bbpose_ros.core.pipeline.hypotheses import DEFAULT_BOX_CONSISTENCY_WEIGHT

if TYPE_CHECKING:
    from rclpy.node import Node

NODE_NAME = 'bbpose_node'
LMO_OBJECTS = ['ape', 'can', 'cat', 'driller', 'duck', 'eggbox', 'glue', 'holepuncher']
RELIABILITY = {'reliable': QoSReliabilityPolicy.RELIABLE,
               'best_effort': QoSReliabilityPolicy.BEST_EFFORT}


def _descriptor(description, read_only=True, int_range=None, float_range=None):
    """Make a ParameterDescriptor; ranges are (from, to) inclusive."""
    descriptor = ParameterDescriptor(description=description, read_only=read_only)
    if int_range is not None:
        descriptor.integer_range = [IntegerRange(from_value=int_range[0],
                                                 to_value=int_range[1], step=1)]
    if float_range is not None:
        descriptor.floating_point_range = [FloatingPointRange(from_value=float_range[0],
                                                              to_value=float_range[1])]
    return descriptor


# name -> (default, descriptor); the default fixes the type (rclpy refuses other types).
PARAMETERS = {
    'objects': (LMO_OBJECTS, _descriptor(
        'Names of the objects to report (BOP LineMod names, e.g. ape); one pose topic each.')),
    'dataset_dir': ('', _descriptor(
        'BOP dataset folder with models/ (meshes in mm, models_info.json) and optionally '
        'models_eval/; empty: $BBPOSE_DATASET, else ../shared/datasets/lmo.')),
    'detector_weights': ('', _descriptor(
        '2D detector weights file (.pt); empty: the weights shipped in bbpose_ros/weights.')),
    'qnet_weights': ('', _descriptor(
        'Q-Net rotation weights file (.pt); empty: the weights shipped in bbpose_ros/weights.')),
    'score_threshold': (0.3, _descriptor(
        'Detections scoring below this (0..1) are ignored.', float_range=(0.0, 1.0))),
    'max_instances': (1, _descriptor(
        'Most instances reported per object and frame.', int_range=(1, 100))),
    'box_consistency_weight': (DEFAULT_BOX_CONSISTENCY_WEIGHT, _descriptor(
        'With a multi-hypothesis Q-Net, how much the Bounding Box '
        'Equation misfit (largest side residual / longest box side) counts against the '
        'log-probability in choosing a rotation; 0: the best-scored one.',
        float_range=(0.0, 1000.0))),
    'inference_backend': ('onnxruntime', _descriptor(
        'What runs the networks: onnxruntime (CPU only) or torch (CPU or GPU).')),
    'device': ('cpu', _descriptor(
        'Torch device of the networks: cpu, cuda or cuda:N (cuda needs the torch backend).')),
    'inference_threads': (0, _descriptor(
        'CPU (intra-op) threads of the inference backend; 0: its default (one per core); '
        '1: a single thread, leaving the other cores to DDS and the executor.',
        int_range=(0, 256))),
    'qos_reliability': ('reliable', _descriptor(
        'Reliability of the image and camera_info subscriptions: reliable or best_effort.')),
    'qos_depth': (1, _descriptor(
        'History depth (keep-last) of the image and camera_info subscriptions; the node '
        'processes only the newest frame whatever the depth.', int_range=(1, 100))),
    'sync_slop': (0.01, _descriptor(
        'Seconds by which image and camera_info header stamps may differ to pair; negative: '
        'pair every image with the latest camera_info.', read_only=False,
        float_range=(-1.0, 10.0))),
    'rectified': (False, _descriptor(
        'True when the images are rectified: use CameraInfo P[:3, :3], otherwise K.',
        read_only=False)),
    'publish_debug_image': (True, _descriptor(
        'Draw and publish ~/debug_image (only while it has subscribers).', read_only=False)),
}


@dataclass(frozen=True)
class NodeConfig:
    """The read-only parameters, validated; paths are None where the shipped files apply."""

    objects: tuple[str, ...]
    dataset_dir: Path
    detector_weights: Path | None
    qnet_weights: Path | None
    score_threshold: float
    max_instances: int
    box_consistency_weight: float
    inference_backend: str
    device: str
    inference_threads: int
    qos: QoSProfile


def declare_parameters(node: Node) -> NodeConfig:
    """
    Declare every parameter on ``node`` and return the validated NodeConfig.

    rclpy raises InvalidParameterTypeException / InvalidParameterValueException for a value
    of the wrong type or out of range; other problems raise InputError naming the parameter.
    """
    for name, (default, descriptor) in PARAMETERS.items():
        node.declare_parameter(name, default, descriptor)
    value = {name: node.get_parameter(name).value for name in PARAMETERS}
    if not value['objects']:
        raise InputError('parameter objects: give at least one object name')
    if value['qos_reliability'] not in RELIABILITY:
        raise InputError(f'parameter qos_reliability: "{value["qos_reliability"]}" is not one '
                         f'of {", ".join(RELIABILITY)}')
    if value['device'] != 'cpu' and not value['device'].startswith('cuda'):
        raise InputError(f'parameter device: "{value["device"]}" is not cpu, cuda or cuda:N')
    if value['inference_backend'] not in BACKENDS:
        raise InputError(f'parameter inference_backend: "{value["inference_backend"]}" is not '
                         f'one of {", ".join(BACKENDS)}')
    if value['inference_backend'] != 'torch' and value['device'] != 'cpu':
        raise InputError(f'parameters inference_backend / device: {value["inference_backend"]} '
                         f'runs on the CPU only; use inference_backend torch for device '
                         f'{value["device"]}')
    return NodeConfig(
        objects=tuple(value['objects']),
        dataset_dir=resolve_dataset_dir(value['dataset_dir']),
        detector_weights=_weights_file('detector_weights', value['detector_weights']),
        qnet_weights=_weights_file('qnet_weights', value['qnet_weights']),
        score_threshold=value['score_threshold'], max_instances=value['max_instances'],
        box_consistency_weight=value['box_consistency_weight'],
        inference_backend=value['inference_backend'], device=value['device'],
        inference_threads=value['inference_threads'],
        qos=QoSProfile(depth=value['qos_depth'],
                       reliability=RELIABILITY[value['qos_reliability']]))


def resolve_dataset_dir(text: str) -> Path:
    """
    Return the dataset folder of parameter ``dataset_dir``.

    Empty means $BBPOSE_DATASET, or the ``bbpose`` tools' default ../shared/datasets/lmo.
    """
    path = Path(text or os.environ.get('BBPOSE_DATASET') or DEFAULT_DATASET)
    if not (path / 'models').is_dir():
        raise InputError(f'parameter dataset_dir: {path} has no models/ folder '
                         f'(BOP meshes and models_info.json)')
    return path


def _weights_file(name, text):
    if not text:
        return None
    path = Path(text)
    if not path.is_file():
        raise InputError(f'parameter {name}: weights file not found: {path}')
    return path


def read_params_file(path: Path | str, overrides: Iterable[str] = (),
                     node_name: str = NODE_NAME) -> dict[str, Any]:
    """
    Read the parameter values a node gets from a ROS 2 parameters file, as rclpy does.

    The ``/**`` block applies first, then the node's own block; ``overrides`` are
    ``name:=value`` strings (YAML values, as ``-p`` takes them) applied last. Parameters
    left unset get their declared default.
    """
    path = Path(path)
    try:
        content = yaml.safe_load(path.read_text()) or {}
    except FileNotFoundError as err:
        raise InputError(f'parameters file not found: {path}') from err
    except yaml.YAMLError as err:
        raise InputError(f'parameters file {path} is not valid YAML: {err}') from err
    values = {name: default for name, (default, _) in PARAMETERS.items()}
    for block in ('/**', node_name, f'/{node_name}'):
        values.update((content.get(block) or {}).get('ros__parameters') or {})
    for override in overrides:
        name, separator, text = override.partition(':=')
        if not separator:
            raise InputError(f'parameter override "{override}" is not name:=value')
        values[name] = yaml.safe_load(text)
    return values


def package_config_file(name: str) -> Path:
    """Return config/<name> of the source tree, else of the installed share/bbpose_ros."""
    source = Path(__file__).resolve().parents[2] / 'config' / name
    if source.is_file():
        return source
    try:
        return Path(get_package_share_directory('bbpose_ros')) / 'config' / name
    except (LookupError, OSError):   # not installed, or AMENT_PREFIX_PATH unset
        return source
