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
(``cli/settings_options.py``) and config/bbpose.yaml (``cli/config_file.py``, ``make
config``) are generated from ``SETTINGS``, declared as every settings class is
(``util.declarations``). A PipelineOptions checks itself when it is made (``check_settings``:
each field, then the combinations), so a value is checked once, wherever it comes from.

The stages take the PipelineOptions itself and read their settings from it by these names
and units (``options.refine_local_colors`` in ``refine.region_modality``,
``options.inference_threads`` in ``inference.backends``): no stage renames, converts,
defaults or checks a setting again, and a stage used alone (in a test) gets its settings
from ``PipelineOptions(...)`` too.

A leaf module: it imports nothing but ``util``, so the parameter table and the
command-line parsers load without torch or numba.
"""

from __future__ import annotations

from dataclasses import dataclass

from bbpose_ros.core.util.declarations import check_settings, declared, setting
from bbpose_ros.core.util.errors import InputError


POSE_SOURCES = ('qnet', 'dense', 'dense+qnet')
DENSE_TRANSLATIONS = ('pnp', 'bbox_equation', 'both')
DENSE_MASKS = ('amodal', 'visible', 'none')
BOX_SOURCES = ('detector', 'dense_mask', 'both')
BACKENDS = ('onnxruntime', 'torch')
PRECISIONS = ('auto', 'fp32', 'int8')


def _device_reason(device: str) -> str | None:
    """Return why ``device`` is no torch device the pipeline takes, or None."""
    return None if device == 'cpu' or device.startswith('cuda') else \
        f'"{device}" is not cpu, cuda or cuda:N'


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

    score_threshold: float = setting(
        0.3, 'Detections scoring below this (0..1) are ignored.', low=0.0, high=1.0)
    max_instances: int = setting(
        1, 'Most instances reported per object and frame.', low=1, high=100)
    box_consistency_weight: float = setting(
        20.0, 'With a multi-hypothesis Q-Net, how much the Bounding Box Equation misfit '
        '(largest side residual / longest box side) counts against the log-probability in '
        'choosing a rotation; 0: the best-scored one.', low=0.0, high=1000.0)
    mask_consistency_weight: float = setting(
        0.0, "With a multi-hypothesis Q-Net, how much each hypothesis' silhouette agreement "
        "(soft IoU, 0..1) with the dense net's amodal mask counts in ranking them; 0: none. "
        'Above 0 the dense net runs on every detection.', low=0.0, high=1000.0)
    refine: bool = setting(
        True, 'Refine each pose by aligning the mesh silhouette with the image '
        '(region-based, no learning); its score becomes the pose confidence.')
    refine_hypotheses: int = setting(
        3, "How many of each detection's best-ranked rotation hypotheses are refined; the "
        'best-scored is kept (cost grows with it). Without refine the best-ranked one alone '
        'is solved.', low=1, high=8)
    refine_min_score: float = setting(
        0.0, 'Refined poses scoring below this (0..1: share of contour lines that agree with '
        'the image) are dropped; 0 keeps all.', low=0.0, high=1.0)
    refine_prior_deg: float = setting(
        0.0, "Standard deviation of a prior around each refinement start's rotation, "
        'degrees: the smaller, the less a start moves; 0: none.', low=0.0, high=180.0)
    refine_prior_mm: float = setting(
        0.0, "The same for the start's translation, millimetres; 0: none.", low=0.0, high=1000.0)
    refine_threads: int = setting(
        1, "Threads the refinement's per-line loops run on, split by pose; 0: one per core. "
        "A frame's few poses gain less from a parallel launch than it costs, and in stream "
        'mode the tracks and the full pipeline each refine on a core of their own.',
        low=0, high=256)
    refine_occlusions: bool = setting(
        True, "The poses of a frame hide each other's contour lines where one is nearer the "
        'camera (the image shows the occluder there).')
    refine_local_colors: int = setting(
        0, "Local colour models (RBOT's): each contour line's foreground and background "
        'colours are sampled on the lines up to this many places before and after it (of '
        "a view's 200); 0: one colour model per pose.", low=0, high=50)
    refine_mask_choice_weight: float = setting(
        8.0, "Where the dense net runs, how much each refined candidate's silhouette "
        'agreement (soft IoU, 0..1) with its amodal mask counts beside the refinement score '
        "in choosing a detection's pose; 0: the score alone. It does not make the dense net "
        'run.', low=0.0, high=1000.0)
    pose_source: str = setting(
        'qnet', "Where each detection's candidate poses come from: qnet (Q-Net + the "
        'Bounding Box Equation, the paper), dense (PnP over the dense correspondences) or '
        'dense+qnet (both).', choices=POSE_SOURCES)
    dense_translation: str = setting(
        'both', "With the dense net: the PnP pose's translation (pnp), the Bounding Box "
        "Equation's from PnP's rotation (bbox_equation), or both candidates.",
        choices=DENSE_TRANSLATIONS)
    dense_mask: str = setting(
        'none', "With refine: the refiner's foreground model, the dense net's predicted "
        'amodal or visible mask, or none (the colours).', choices=DENSE_MASKS)
    box_source: str = setting(
        'detector', "The amodal box the Bounding Box Equation solves with: the detector's "
        "(detector), the detector's corrected by the dense net's amodal mask on each "
        "detection's crop (dense_mask; the dense net runs on every detection), or a "
        'candidate from each for the refiner to choose (both).', choices=BOX_SOURCES)
    tracking: bool = setting(
        False, 'Start each refined object from its pose in the previous frame and run the '
        'detector and Q-Net only when needed (needs refine).')
    tracking_redetect_every: int = setting(
        10, 'With tracking, run the detector and Q-Net at least every this many frames, so '
        'new objects are found.', low=1, high=1000)
    tracking_min_score: float = setting(
        0.5, 'With tracking, a track whose refinement scores below this (0..1) is lost.',
        low=0.0, high=1.0)
    tracking_stream: bool = setting(
        False, 'With tracking, answer every frame from the tracks alone and run the detector, '
        'Q-Net and refinement beside it in a thread of their own on the newest frame; their '
        'poses join the tracks when they arrive (needs tracking).')
    tracking_in_place_pose_source: str = setting(
        'dense+qnet', 'In stream mode, the pose_source of a frame detected in the frame itself '
        "when the camera's frame period holds that route's run time (a slow camera); "
        "otherwise, and for a stream's first frame, pose_source.", choices=POSE_SOURCES)
    map_depth_sigma: float = setting(
        0.04, "The map's model of one view: the standard deviation of its depth along the "
        'viewing ray, as a fraction of the distance.', low=0.001, high=1.0)
    map_across_sigma_px: float = setting(
        2.0, "The same across the ray, pixels at the object's distance.", low=0.01, high=100.0)
    map_camera_sigma_mm: float = setting(
        2.0, "Standard deviation of the camera pose's position error (the TF's: kinematics, "
        'hand-eye calibration, odometry), millimetres, in the map.', low=0.0, high=1000.0)
    map_camera_sigma_deg: float = setting(
        0.2, 'The same of its rotation error, degrees.', low=0.0, high=90.0)
    map_gate_deg: float = setting(
        15.0, 'Two views of an object agree in the map when their rotations are within this '
        '(and their translations within the 99 % ellipsoid of their covariances), degrees.',
        low=0.1, high=180.0)
    map_window: int = setting(
        30, 'Most views of an object the map fuses (the newest).', low=1, high=1000)
    map_keyframe_deg: float = setting(
        2.0, "A view whose ray to an object is within this of the object's newest view's "
        '(the camera hardly moved) adds nothing to the map where it agrees with it, and '
        'replaces that view where not: views from one place share their depth error, '
        'degrees.', low=0.0, high=90.0)
    map_move_views: int = setting(
        3, 'An object was moved when this many views in a row, each from a ray '
        'map_keyframe_deg from the one before, place it elsewhere and agree with each '
        'other: the map starts it afresh from them.', low=1, high=100)
    inference_backend: str = setting(
        'onnxruntime', 'What runs the networks: onnxruntime (CPU only) or torch (CPU or GPU).',
        choices=BACKENDS)
    inference_precision: str = setting(
        'auto', 'What the detector and Q-Net run as: fp32, int8 (the int8 graph <weights '
        'stem>_int8.onnx beside each weight file; onnxruntime only) or auto (int8 where those '
        'graphs exist on a CPU with AVX2 or int8 dot-product instructions, else fp32).',
        choices=PRECISIONS)
    device: str = setting(
        'cpu', 'Torch device of the networks: cpu, cuda or cuda:N (cuda needs the torch '
        'backend).', check=_device_reason)
    inference_threads: int = setting(
        0, 'CPU (intra-op) threads of the inference backend; 0: its default (one per core).',
        low=0, high=256)

    def __post_init__(self) -> None:
        check_settings(self)
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


SETTINGS = declared(PipelineOptions)
