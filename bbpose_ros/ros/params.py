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
The parameters of ``bbpose_node``: one table of declarations, descriptors and checks.

Each parameter says when the node reads it (``ParameterSpec.applies``):

* ``start``: once, when the process starts (read-only);
* ``configure``: by the configure transition; settable while the node is unconfigured;
* ``pipeline``: shapes the pipeline; a run-time set rebuilds it off the executor thread
  while the node keeps serving with the pipeline it has, and swaps it in when built;
* ``frame``: read for every frame; settable at any time.

Every setting of ``PipelineOptions`` is a parameter of the same name, its descriptor
generated from the setting's declaration (``options.SETTINGS``: type, default, range,
description), so the node, ``bbpose eval`` and ``bbpose bench`` share them; its value is
checked by making the PipelineOptions (``NodeConfig.updated`` / ``read_config``). The
node's own parameters (topics, QoS, TF, files) are declared in the table below and checked
by ``check_value`` (the row type and the checks: ``param_specs.py``). ``config/bbpose.yaml``
documents each one, with these defaults (a test holds them equal).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, TYPE_CHECKING

from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, QoSReliabilityPolicy

from bbpose_ros.core.data.models import LMO_OBJECTS
from bbpose_ros.core.inference.options import PipelineOptions, SETTINGS
from bbpose_ros.core.util.declarations import Setting
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.ros.param_specs import check_dataset_dir, check_object_names, check_tf_prefix
from bbpose_ros.ros.param_specs import check_weights_file, dataset_path, one_of, ParameterSpec

if TYPE_CHECKING:
    from rclpy.node import Node

NODE_NAME = 'bbpose_node'
RELIABILITY = {'reliable': QoSReliabilityPolicy.RELIABLE,
               'best_effort': QoSReliabilityPolicy.BEST_EFFORT}
# image_transport's names of how images arrive: raw sensor_msgs/Image on ``image``, or
# sensor_msgs/CompressedImage (JPEG, PNG) on ``<image>/compressed``.
TRANSPORTS = ('raw', 'compressed')

# The settings the configure transition reads (what runs the networks); the others shape
# the pipeline and may be set while the node runs.
CONFIGURE_SETTINGS = ('inference_backend', 'inference_precision', 'device',
                      'inference_threads')
# Where the node's default differs from the pipeline's: one inference thread leaves the
# other core of a 2-core robot to DDS, the executor and the camera driver.
NODE_DEFAULTS = {'inference_threads': 1}


def setting_spec(setting: Setting) -> ParameterSpec:
    """Make the ParameterSpec of a PipelineOptions setting, from its declaration."""
    return ParameterSpec(NODE_DEFAULTS.get(setting.name, setting.default), setting.description,
                         'configure' if setting.name in CONFIGURE_SETTINGS else 'pipeline',
                         value_range=setting.limits, option=True)


# The table: name -> ParameterSpec, in the order of config/bbpose.yaml.
PARAMETERS = {
    'autostart': ParameterSpec(
        True, 'Configure and activate at start; false: wait in the unconfigured state for '
        'the lifecycle services.', 'start'),
    'objects': ParameterSpec(
        list(LMO_OBJECTS), "Names of the objects to report (the dataset's: "
        "models/models_names.json, else LineMod's by BOP id, e.g. ape); one pose topic each.",
        'pipeline', check=check_object_names),
    'dataset_dir': ParameterSpec(
        '', 'BOP dataset folder with models/ (meshes in mm, models_info.json) and optionally '
        'models_eval/; empty: $BBPOSE_DATASET, else ../shared/datasets/lmo.', 'configure',
        check=check_dataset_dir),
    'detector_weights': ParameterSpec(
        '', '2D detector weights file (.pt); empty: the weights shipped in bbpose_ros/weights.',
        'configure', check=check_weights_file),
    'qnet_weights': ParameterSpec(
        '', 'Q-Net rotation weights file (.pt); empty: the weights shipped in '
        'bbpose_ros/weights.', 'configure', check=check_weights_file),
    'dense_weights': ParameterSpec(
        '', 'Dense correspondence net weights file (.pt), read when pose_source, dense_mask, '
        'box_source, mask_consistency_weight or, in stream mode, tracking_in_place_pose_source '
        'uses it; empty: bbpose_ros/weights/dense.pt.',
        'configure',
        check=check_weights_file),
    **{name: setting_spec(setting) for name, setting in SETTINGS.items()},
    'image_transport': ParameterSpec(
        'raw', 'How images arrive, as image_transport names it: raw (sensor_msgs/Image on '
        'image) or compressed (sensor_msgs/CompressedImage, JPEG or PNG, on the resolved '
        'image topic + /compressed, e.g. /camera/image_raw/compressed; decoded in the '
        'worker thread, only the frames it takes).', 'configure', check=one_of(TRANSPORTS)),
    'qos_reliability': ParameterSpec(
        'reliable', 'Reliability of the image and camera_info subscriptions: reliable or '
        'best_effort.', 'configure', check=one_of(RELIABILITY)),
    'qos_depth': ParameterSpec(
        1, 'History depth (keep-last) of the image and camera_info subscriptions; the node '
        'processes only the newest frame whatever the depth.', 'configure',
        value_range=(1, 100)),
    'sync_slop': ParameterSpec(
        0.01, 'Seconds by which image and camera_info header stamps may differ to pair; '
        'negative: pair every image with the latest camera_info.', 'frame',
        value_range=(-1.0, 10.0)),
    'rectified': ParameterSpec(
        False, 'True when the images are rectified: use CameraInfo P[:3, :3]; false: K, and '
        'a distorted image (plumb_bob, rational_polynomial, equidistant D) is rectified.',
        'frame'),
    'publish_debug_image': ParameterSpec(
        True, 'Draw and publish ~/debug_image (only while it has subscribers).', 'frame'),
    'publish_tf': ParameterSpec(
        True, 'Publish one /tf transform per pose: image frame_id -> <tf_prefix><object> '
        '(<object>_<k> for the k-th further instance).', 'frame'),
    'tf_prefix': ParameterSpec(
        '~/', 'Prefix of the TF child frames and Detection3D ids; a leading ~/ stands for the '
        "node's name and a slash (bbpose_node/ape); empty: the bare object names.",
        'frame', check=check_tf_prefix),
    'fixed_frame': ParameterSpec(
        '', "The robot's fixed frame (e.g. world, base_link): the camera's pose in it at each "
        "image's stamp, from /tf and /tf_static, fuses each object's poses over the "
        "camera's motion into a map published in it (~/map/...); empty: no map.",
        'configure', check=check_tf_prefix),
    'max_image_pixels': ParameterSpec(
        33_554_432, 'Images of more pixels (width x height) are dropped unread.', 'frame',
        value_range=(1, 2 ** 31 - 1)),
}


@dataclass(frozen=True)
class NodeConfig:
    """
    The parameter values the configure transition read and checked, and what they resolve to.

    Attributes:
        values: {name: value} of every parameter of PARAMETERS.
        dataset_dir: the dataset folder ``dataset_dir`` resolves to.
        detector_weights, qnet_weights, dense_weights: the weight files; None where the
            shipped one applies.
        qos: the input subscriptions' QoS (``qos_reliability``, ``qos_depth``).
        options: the PipelineOptions of the settings' parameters.

    """

    values: dict[str, Any]
    dataset_dir: Path
    detector_weights: Path | None
    qnet_weights: Path | None
    dense_weights: Path | None
    qos: QoSProfile
    options: PipelineOptions

    @property
    def objects(self) -> tuple[str, ...]:
        """Return the names of the objects to report."""
        return tuple(self.values['objects'])

    @property
    def image_transport(self) -> str:
        """Return how images arrive: 'raw' or 'compressed' (TRANSPORTS)."""
        return self.values['image_transport']

    def updated(self, changes: dict[str, Any], options: PipelineOptions) -> NodeConfig:
        """
        Return this config with ``changes`` ({name: value}, ``pipeline`` ones) applied.

        ``options`` are the PipelineOptions that ``checked_options`` made of the values with
        the changes when they were set: checked then, not again.
        """
        return replace(self, values={**self.values, **changes}, options=options)


def checked_options(values: dict[str, Any]) -> PipelineOptions:
    """
    Return the PipelineOptions of parameter ``values`` ({name: value}, every parameter).

    Making it checks each setting's value and their combinations (once); raises
    InputError 'parameter(s) <name(s)>: reason' for the first that is wrong.
    """
    try:
        return PipelineOptions(**{name: values[name] for name in SETTINGS})
    except InputError as err:      # 'name: reason' or 'name / name: reason'
        names, _, reason = str(err).partition(': ')
        plural = 's' if ' / ' in names else ''
        raise InputError(f'parameter{plural} {names}: {reason}') from err


def declare_parameters(node: Node) -> None:
    """
    Declare every parameter of PARAMETERS on ``node``, with its descriptor.

    rclpy raises InvalidParameterTypeException / InvalidParameterValueException for an
    override of the wrong type or out of range.
    """
    for name, spec in PARAMETERS.items():
        node.declare_parameter(name, spec.default, spec.descriptor)


def check_value(name: str, value: Any) -> None:
    """
    Raise InputError naming parameter ``name`` when ``value`` is not one it takes.

    Every parameter's type is checked here (as rclpy types it: ``1`` is no double); the
    value of a setting of PipelineOptions is checked when its options are made
    (``checked_options``), so only the node's own parameters get their range and check here.
    """
    spec = PARAMETERS[name]
    expected = Parameter.Type.from_parameter_value(spec.default)
    # An empty list has no element type; the parameter's own check judges it.
    if value != [] and Parameter.Type.from_parameter_value(value) != expected:
        raise InputError(f'parameter {name}: {value!r} is not of type '
                         f'{expected.name.lower()}')
    if spec.option:
        return
    limits = spec.value_range
    if limits is not None and not limits[0] <= value <= limits[1]:
        raise InputError(f'parameter {name}: {value} is out of range [{limits[0]}, '
                         f'{limits[1]}]')
    if spec.check is not None:
        try:
            spec.check(value)
        except InputError as err:
            raise InputError(f'parameter {name}: {err}') from err


def read_config(values: dict[str, Any]) -> NodeConfig:
    """
    Check parameter ``values`` ({name: value}, every parameter) and make the NodeConfig.

    Raises InputError naming the first parameter that is wrong.
    """
    for name in PARAMETERS:
        check_value(name, values[name])
    options = checked_options(values)
    return NodeConfig(
        values=dict(values), dataset_dir=resolve_dataset_dir(values['dataset_dir']),
        detector_weights=Path(values['detector_weights']) if values['detector_weights']
        else None,
        qnet_weights=Path(values['qnet_weights']) if values['qnet_weights'] else None,
        dense_weights=Path(values['dense_weights']) if values['dense_weights'] else None,
        qos=QoSProfile(depth=values['qos_depth'],
                       reliability=RELIABILITY[values['qos_reliability']]),
        options=options)


def parameter_values(node: Node) -> dict[str, Any]:
    """Return {name: current value} of every parameter of PARAMETERS on ``node``."""
    return {name: node.get_parameter(name).value for name in PARAMETERS}


def resolve_dataset_dir(text: str) -> Path:
    """
    Return the dataset folder of parameter ``dataset_dir``.

    Empty means $BBPOSE_DATASET, or the ``bbpose`` tools' default ../shared/datasets/lmo.
    """
    check_value('dataset_dir', text)
    return dataset_path(text)
