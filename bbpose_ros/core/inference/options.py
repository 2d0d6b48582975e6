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
``PipelineOptions``: every setting of the run-time pipeline, declared once.

Each field is one setting, under one name from the node's parameters file to the stage
that reads it: its type, default (the shipped value), range or choices and a one-line
description live here and nowhere else. The node's parameter descriptors
(``ros/params.py``), the ``bbpose eval`` / ``bbpose bench`` options
(``cli/pipeline_arguments.py``) and config/bbpose.yaml (``cli/config_file.py``, ``make
config``) are generated from ``SETTINGS``. A PipelineOptions checks itself when it is made
(``check_option`` for each field, then the combinations), so a value is checked once,
wherever it comes from.

The stages take the PipelineOptions itself and read their settings from it by these names
and units (``options.refine_local_colors`` in ``refine.refiner``, ``options.inference_threads``
in ``inference.backends``): no stage renames, converts, defaults or checks a setting again,
and a stage used alone (in a test) gets its settings from ``PipelineOptions(...)`` too.

A leaf module: it imports nothing but the errors, so the parameter table and the
command-line parsers load without torch or numba.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

from bbpose_ros.core.util.errors import InputError


POSE_SOURCES = ('qnet', 'dense', 'dense+qnet')
DENSE_TRANSLATIONS = ('pnp', 'bbox_equation', 'both')
DENSE_MASKS = ('amodal', 'visible', 'none')
BOX_SOURCES = ('detector', 'dense_mask', 'both')
BACKENDS = ('onnxruntime', 'torch')
PRECISIONS = ('auto', 'fp32', 'int8')


def _setting(default: Any, description: str, low: float | None = None,
             high: float | None = None, choices: tuple[str, ...] | None = None) -> Any:
    """Make a dataclass field with its description and inclusive range or choices."""
    return field(default=default, metadata={
        'description': description, 'range': None if low is None else (low, high),
        'choices': choices})


@dataclass(frozen=True)
class PipelineOptions:
    """
    Settings of the pipeline built by ``pipeline.loader.load_pipeline``; defaults shipped.

    Each field's description is in its declaration below (``SETTINGS`` lists them with
    their types, ranges and choices). Units: millimetres and degrees where a name says so,
    scores and weights unitless.

    Raises:
        InputError: 'name: reason' (or 'name / name: reason') for the first value, or
            combination, it does not take.

    """

    score_threshold: float = _setting(
        0.3, 'Detections scoring below this (0..1) are ignored.', 0.0, 1.0)
    max_instances: int = _setting(
        1, 'Most instances reported per object and frame.', 1, 100)
    box_consistency_weight: float = _setting(
        20.0, 'With a multi-hypothesis Q-Net, how much the Bounding Box Equation misfit '
        '(largest side residual / longest box side) counts against the log-probability in '
        'choosing a rotation; 0: the best-scored one.', 0.0, 1000.0)
    mask_consistency_weight: float = _setting(
        0.0, "With a multi-hypothesis Q-Net, how much each hypothesis' silhouette agreement "
        "(soft IoU, 0..1) with the dense net's amodal mask counts in ranking them; 0: none. "
        'Above 0 the dense net runs on every detection.', 0.0, 1000.0)
    refine: bool = _setting(
        True, 'Refine each pose by aligning the mesh silhouette with the image '
        '(region-based, no learning); its score becomes the pose confidence.')
    refine_hypotheses: int = _setting(
        3, "How many of each detection's best-ranked rotation hypotheses are refined; the "
        'best-scored is kept (cost grows with it). Without refine the best-ranked one alone '
        'is solved.', 1, 8)
    refine_min_score: float = _setting(
        0.0, 'Refined poses scoring below this (0..1: share of contour lines that agree with '
        'the image) are dropped; 0 keeps all.', 0.0, 1.0)
    refine_prior_deg: float = _setting(
        0.0, "Standard deviation of a prior around each refinement start's rotation, "
        'degrees: the smaller, the less a start moves; 0: none.', 0.0, 180.0)
    refine_prior_mm: float = _setting(
        0.0, "The same for the start's translation, millimetres; 0: none.", 0.0, 1000.0)
    refine_threads: int = _setting(
        1, "Threads the refinement's per-line loops run on, split by pose; 0: one per core. "
        "A frame's few poses gain less from a parallel launch than it costs, and in stream "
        'mode the tracks and the full pipeline each refine on a core of their own.', 0, 256)
    refine_occlusions: bool = _setting(
        True, "The poses of a frame hide each other's contour lines where one is nearer the "
        'camera (the image shows the occluder there).')
    refine_local_colors: int = _setting(
        0, "Local colour models (RBOT's): each contour line's foreground and background "
        'colours are sampled on the lines up to this many places before and after it (of '
        "a view's 200); 0: one colour model per pose.", 0, 50)
    refine_mask_choice_weight: float = _setting(
        8.0, "Where the dense net runs, how much each refined candidate's silhouette "
        'agreement (soft IoU, 0..1) with its amodal mask counts beside the refinement score '
        "in choosing a detection's pose; 0: the score alone. It does not make the dense net "
        'run.', 0.0, 1000.0)
    pose_source: str = _setting(
        'qnet', "Where each detection's candidate poses come from: qnet (Q-Net + the "
        'Bounding Box Equation, the paper), dense (PnP over the dense correspondences) or '
        'dense+qnet (both).', choices=POSE_SOURCES)
    dense_translation: str = _setting(
        'both', "With the dense net: the PnP pose's translation (pnp), the Bounding Box "
        "Equation's from PnP's rotation (bbox_equation), or both candidates.",
        choices=DENSE_TRANSLATIONS)
    dense_mask: str = _setting(
        'none', "With refine: the refiner's foreground model, the dense net's predicted "
        'amodal or visible mask, or none (the colours).', choices=DENSE_MASKS)
    box_source: str = _setting(
        'detector', "The amodal box the Bounding Box Equation solves with: the detector's "
        "(detector), the detector's corrected by the dense net's amodal mask on each "
        "detection's crop (dense_mask; the dense net runs on every detection), or a "
        'candidate from each for the refiner to choose (both).', choices=BOX_SOURCES)
    tracking: bool = _setting(
        False, 'Start each refined object from its pose in the previous frame and run the '
        'detector and Q-Net only when needed (needs refine).')
    tracking_redetect_every: int = _setting(
        10, 'With tracking, run the detector and Q-Net at least every this many frames, so '
        'new objects are found.', 1, 1000)
    tracking_min_score: float = _setting(
        0.5, 'With tracking, a track whose refinement scores below this (0..1) is lost.',
        0.0, 1.0)
    tracking_stream: bool = _setting(
        False, 'With tracking, answer every frame from the tracks alone and run the detector, '
        'Q-Net and refinement beside it in a thread of their own on the newest frame; their '
        'poses join the tracks when they arrive (needs tracking).')
    tracking_in_place_pose_source: str = _setting(
        'dense+qnet', 'In stream mode, the pose_source of a frame detected in the frame itself '
        "when the camera's frame period holds that route's run time (a slow camera); "
        "otherwise, and for a stream's first frame, pose_source.", choices=POSE_SOURCES)
    map_depth_sigma: float = _setting(
        0.04, "The map's model of one view: the standard deviation of its depth along the "
        'viewing ray, as a fraction of the distance.', 0.001, 1.0)
    map_across_sigma_px: float = _setting(
        2.0, "The same across the ray, pixels at the object's distance.", 0.01, 100.0)
    map_camera_sigma_mm: float = _setting(
        2.0, "Standard deviation of the camera pose's position error (the TF's: kinematics, "
        'hand-eye calibration, odometry), millimetres, in the map.', 0.0, 1000.0)
    map_camera_sigma_deg: float = _setting(
        0.2, 'The same of its rotation error, degrees.', 0.0, 90.0)
    map_gate_deg: float = _setting(
        15.0, 'Two views of an object agree in the map when their rotations are within this '
        '(and their translations within the 99 % ellipsoid of their covariances), degrees.',
        0.1, 180.0)
    map_window: int = _setting(
        30, 'Most views of an object the map fuses (the newest).', 1, 1000)
    map_keyframe_deg: float = _setting(
        2.0, "A view whose ray to an object is within this of the object's newest view's "
        '(the camera hardly moved) replaces that view in the map instead of joining it: '
        'views from one place share their depth error, degrees.', 0.0, 90.0)
    map_move_views: int = _setting(
        3, 'An object is moved when this many of its newest views agree with each other and '
        'not with the map: its older views are dropped.', 1, 100)
    inference_backend: str = _setting(
        'onnxruntime', 'What runs the networks: onnxruntime (CPU only) or torch (CPU or GPU).',
        choices=BACKENDS)
    inference_precision: str = _setting(
        'auto', 'What the detector and Q-Net run as: fp32, int8 (the int8 graph <weights '
        'stem>_int8.onnx beside each weight file; onnxruntime only) or auto (int8 where those '
        'graphs exist on a CPU with AVX2 or int8 dot-product instructions, else fp32).',
        choices=PRECISIONS)
    device: str = _setting(
        'cpu', 'Torch device of the networks: cpu, cuda or cuda:N (cuda needs the torch '
        'backend).')
    inference_threads: int = _setting(
        0, 'CPU (intra-op) threads of the inference backend; 0: its default (one per core).',
        0, 256)

    def __post_init__(self) -> None:
        for setting in fields(self):
            check_option(setting.name, getattr(self, setting.name))
        if self.inference_backend != 'torch' and self.device != 'cpu':
            raise InputError(f'inference_backend / device: {self.inference_backend} runs on '
                             f'the CPU only; use the torch backend for device {self.device}')
        if self.inference_precision == 'int8' and self.inference_backend != 'onnxruntime':
            raise InputError(f'inference_precision / inference_backend: the int8 graphs run '
                             f'on onnxruntime, not {self.inference_backend}')
        if self.tracking and not self.refine:
            raise InputError('tracking / refine: tracking follows refined poses; set refine '
                             'true or tracking false')
        if self.tracking_stream and not self.tracking:
            raise InputError('tracking_stream / tracking: stream mode runs beside the tracks; '
                             'set tracking true or tracking_stream false')

    @property
    def uses_qnet(self) -> bool:
        """Tell whether Q-Net's hypotheses are candidates."""
        return self.pose_source in ('qnet', 'dense+qnet')

    @property
    def uses_dense(self) -> bool:
        """Tell whether the dense net's PnP poses are candidates."""
        return self.pose_source in ('dense', 'dense+qnet')

    @property
    def ranks_by_mask(self) -> bool:
        """Tell whether Q-Net's hypotheses are ranked by the dense net's amodal masks too."""
        return self.uses_qnet and self.mask_consistency_weight > 0.0

    def runs_dense(self, rotations_given: bool = False) -> bool:
        """
        Tell whether the dense net runs: for its PnP poses or its masks.

        With ``rotations_given`` (the ground truth replaces the rotations) its poses are not
        wanted, so it runs only where it would otherwise and its masks are used: as the
        refiner's foreground or in choosing among refined candidates. Wherever its masks
        correct the boxes (``box_source``) it runs, rotations given or not.
        """
        runs = self.uses_dense or (self.refine and self.dense_mask != 'none') or \
            self.ranks_by_mask
        if rotations_given:
            runs = runs and self.refine and (
                self.dense_mask != 'none' or self.refine_mask_choice_weight > 0.0)
        return runs or self.corrects_boxes

    @property
    def corrects_boxes(self) -> bool:
        """Tell whether the dense net's amodal masks correct the detections' boxes."""
        return self.box_source != 'detector'


@dataclass(frozen=True)
class Setting:
    """
    One field of PipelineOptions as the generators see it.

    Attributes:
        name: the field's name, also the node parameter's and (dashed) the CLI option's.
        kind: the Python type, bool, int, float or str.
        default: the shipped value.
        description: one line, with units.
        limits: inclusive (low, high), or None.
        choices: the values a str setting takes, or None.

    """

    name: str
    kind: type
    default: Any
    description: str
    limits: tuple[float, float] | None
    choices: tuple[str, ...] | None


_TYPES = {'bool': bool, 'int': int, 'float': float, 'str': str}
SETTINGS = {option.name: Setting(option.name, _TYPES[option.type], option.default,
                                 option.metadata['description'], option.metadata['range'],
                                 option.metadata['choices'])
            for option in fields(PipelineOptions)}


def check_option(name: str, value: Any) -> None:
    """Raise InputError 'name: reason' when ``value`` is not one setting ``name`` takes."""
    setting = SETTINGS[name]
    expected = setting.kind
    # bool is an int in Python; an int is a fine float; neither is accepted the other way.
    accepted = isinstance(value, expected) and not (expected is int and isinstance(value, bool))
    if expected is float:
        accepted = isinstance(value, (int, float)) and not isinstance(value, bool)
    if not accepted:
        raise InputError(f'{name}: {value!r} is not of type {expected.__name__}')
    limits, choices = setting.limits, setting.choices
    if limits is not None and not limits[0] <= value <= limits[1]:
        raise InputError(f'{name}: {value} is out of range [{limits[0]}, {limits[1]}]')
    if choices is not None and value not in choices:
        raise InputError(f'{name}: "{value}" is not one of {", ".join(choices)}')
    if name == 'device' and value != 'cpu' and not value.startswith('cuda'):
        raise InputError(f'{name}: "{value}" is not cpu, cuda or cuda:N')
