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
Weight files of the learned stages: a state dict plus metadata checked at load time.

A file is a ``torch.save`` of ``{'metadata': dict, 'state_dict': dict}`` that loads with
``weights_only=True`` (no pickled code). Metadata fields:

* ``format_version``: FORMAT_VERSION; other versions are refused.
* ``kind``: 'qnet', 'detector' or 'dense' (the dense correspondence net).
* ``objects``: object names, in the network's output order.
* ``input_size``: [width, height] of the network input in pixels.
* ``rotation_convention``: Q-Net only: {'quaternion_order': 'wxyz', 'hemisphere': 'q0>=0',
  'target': 'egocentric' | 'allocentric', 'frame': 'model-to-camera (OpenCV optical)'}.
* ``coordinate_convention``: dense only: {'normalisation': 'model box', 'map_size': M,
  'channels': [...], 'symmetric_targets': ...}: what the output maps mean
  (``geometry.dense_grid``, ``nets.dense``).
* ``architecture``: the QNetConfig, DetectorConfig or DenseConfig as a dict.
* ``training``: {'command', 'git_commit', 'steps', ...} as recorded by the trainer.

Any mismatch or a corrupt file raises InputError naming the file and the field.
"""

from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import torch

from bbpose_ros.core.nets.dense import DenseConfig, DenseNet
from bbpose_ros.core.nets.detector import CenterBoxNet, DetectorConfig
from bbpose_ros.core.nets.qnet import QNet, QNetConfig
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.core.util.files import atomic_output

FORMAT_VERSION = 1
WEIGHTS_DIR = Path(__file__).resolve().parents[2] / 'weights'
DEFAULT_DETECTOR_WEIGHTS = WEIGHTS_DIR / 'detector.pt'
DEFAULT_QNET_WEIGHTS = WEIGHTS_DIR / 'qnet.pt'
DEFAULT_DENSE_WEIGHTS = WEIGHTS_DIR / 'dense.pt'
QUATERNION_ORDER = 'wxyz'
# What a dense net's maps mean; a file saying otherwise is refused.
DENSE_COORDINATES = {'normalisation': 'model box: (x - min) / size, metres, model frame',
                     'channels': ['x', 'y', 'z', 'visible_logit', 'amodal_logit'],
                     'symmetric_targets': 'closest to the identity (allocentric)'}

_KINDS = {'qnet': (QNetConfig, QNet), 'detector': (DetectorConfig, CenterBoxNet),
          'dense': (DenseConfig, DenseNet)}
Config = QNetConfig | DetectorConfig | DenseConfig
Network = QNet | CenterBoxNet | DenseNet


def metadata_for(kind: str, config: Config, training: Mapping[str, Any]) -> dict[str, Any]:
    """Build the metadata dict of a network of ``kind`` with ``config`` and training record."""
    if kind in ('qnet', 'dense'):
        input_size = [config.crop_size, config.crop_size]
    else:
        input_size = list(config.input_size)
    metadata = {'format_version': FORMAT_VERSION, 'kind': kind,
                'objects': list(config.objects), 'input_size': input_size,
                'architecture': config.to_dict(), 'training': dict(training)}
    if kind == 'qnet':
        metadata['rotation_convention'] = {
            'quaternion_order': QUATERNION_ORDER, 'hemisphere': 'q0>=0',
            'target': config.rotation_target,
            'frame': 'model-to-camera (OpenCV optical)'}
    if kind == 'dense':
        metadata['coordinate_convention'] = dict(DENSE_COORDINATES, map_size=config.map_size)
    return metadata


def save_weights(path: Path | str, network: Network, kind: str,
                 training: Mapping[str, Any], config: Config | None = None) -> None:
    """
    Write ``network`` (QNet, CenterBoxNet or DenseNet) with its metadata, atomically.

    ``config`` is recorded instead of ``network.config`` when given: a fully convolutional
    detector may be run at another input size than the one it trained at.
    """
    path = Path(path)
    state = {k: v.detach().cpu().clone() for k, v in network.state_dict().items()}
    payload = {'metadata': metadata_for(kind, config or network.config, training),
               'state_dict': state}
    with atomic_output(path) as tmp:
        torch.save(payload, tmp)


def read_weights(path: Path | str, kind: str) -> tuple[dict[str, Any], dict[str, torch.Tensor]]:
    """
    Read and check a weight file; returns (metadata, state_dict).

    Raises InputError naming the file and the field for a missing, corrupt or foreign file.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f'weight file not found: {path}')
    try:
        payload = torch.load(path, map_location='cpu', weights_only=True)
    except Exception as err:  # torch raises many types for a damaged file
        raise InputError(f'corrupt weight file {path}: {err}') from err
    if not isinstance(payload, dict) or not isinstance(payload.get('metadata'), dict):
        raise InputError(f'weight file {path}: field "metadata" is missing')
    metadata = payload['metadata']
    _expect(path, metadata, 'format_version', FORMAT_VERSION)
    _expect(path, metadata, 'kind', kind)
    if not isinstance(payload.get('state_dict'), dict):
        raise InputError(f'weight file {path}: field "state_dict" is missing')
    return metadata, payload['state_dict']


def load_network(path: Path | str, kind: str, objects: Iterable[str] | None = None,
                 input_size: Sequence[int] | None = None,
                 rotation_target: str | None = None) -> Network:
    """
    Build the network stored in ``path`` and check it against what the caller needs.

    Args:
        path: weight file.
        kind: 'qnet', 'detector' or 'dense'.
        objects: names the caller needs; each must be in the file's ``objects``.
        input_size: optional expected [width, height].
        rotation_target: optional expected Q-Net target ('egocentric' / 'allocentric').

    Returns:
        The network in eval mode, with its metadata as ``network.metadata``.

    """
    path = Path(path)
    metadata, state = read_weights(path, kind)
    config_type, network_type = _KINDS[kind]
    try:
        config = config_type.from_dict(metadata['architecture'])
    except (KeyError, TypeError, ValueError) as err:
        raise InputError(f'weight file {path}: field "architecture" is invalid ({err})') from err
    _expect(path, metadata, 'objects', list(config.objects))
    missing = [name for name in objects or () if name not in config.objects]
    if missing:
        raise InputError(f'weight file {path}: field "objects" lacks {", ".join(missing)} '
                         f'(has {", ".join(config.objects)})')
    expected_size = metadata_for(kind, config, {})['input_size']
    _expect(path, metadata, 'input_size', list(input_size) if input_size else expected_size)
    if kind == 'qnet':
        convention = metadata.get('rotation_convention')
        if not isinstance(convention, dict) or convention.get('quaternion_order') != 'wxyz' \
                or convention.get('target') != config.rotation_target:
            raise InputError(f'weight file {path}: field "rotation_convention" is '
                             f'{convention!r}, inconsistent with the architecture')
        if rotation_target and rotation_target != config.rotation_target:
            raise InputError(f'weight file {path}: field "rotation_convention.target" is '
                             f'{config.rotation_target!r}, expected {rotation_target!r}')
    if kind == 'dense':
        _expect(path, metadata, 'coordinate_convention',
                dict(DENSE_COORDINATES, map_size=config.map_size))
    network = network_type(config)
    try:
        network.load_state_dict(state)
    except RuntimeError as err:
        raise InputError(f'weight file {path}: field "state_dict" does not fit the '
                         f'architecture ({err})') from err
    network.eval()
    network.metadata = metadata
    return network


def _expect(path, metadata, field, expected):
    if field not in metadata:
        raise InputError(f'weight file {path}: field "{field}" is missing')
    if metadata[field] != expected:
        raise InputError(f'weight file {path}: field "{field}" is {metadata[field]!r}, '
                         f'expected {expected!r}')
