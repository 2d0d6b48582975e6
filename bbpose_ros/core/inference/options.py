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
``PipelineOptions``: every setting of the run-time pipeline, its default and its check.

The one place that states them: ``loader.load_pipeline`` builds the pipeline from a
PipelineOptions, the node's parameter table takes its defaults and ranges from here, and
``bbpose eval`` / ``bbpose bench`` fill one from their options. A value is checked once,
by ``check_option`` (which construction runs for every field), so the node refuses a
run-time parameter set with the same message that a bad command-line option gets.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

from bbpose_ros.core.errors import InputError
from bbpose_ros.core.inference.backends import BACKENDS
from bbpose_ros.core.pipeline.hypotheses import DEFAULT_BOX_CONSISTENCY_WEIGHT
from bbpose_ros.core.refine.refiner import RefinerConfig


POSE_SOURCES = ('qnet', 'dense', 'dense+qnet')
DENSE_TRANSLATIONS = ('pnp', 'bbox_equation', 'both')
DENSE_MASKS = ('amodal', 'visible', 'none')
PRECISIONS = ('auto', 'fp32', 'int8')


def _option(default: Any, low: float | None = None, high: float | None = None,
            choices: tuple[str, ...] | None = None) -> Any:
    """Make a dataclass field with its inclusive range or its choices as metadata."""
    return field(default=default, metadata={'range': None if low is None else (low, high),
                                            'choices': choices})


@dataclass(frozen=True)
class PipelineOptions:
    """
    Settings of the pipeline built by ``load_pipeline``; the defaults are the shipped ones.

    Attributes:
        score_threshold: lowest detector score reported, 0..1.
        max_instances: most detections per object and frame.
        box_consistency_weight: with a multi-hypothesis Q-Net, how much the Bounding Box
            Equation's misfit counts in choosing a rotation (``hypotheses``); 0: the
            network's best-scored one.
        mask_consistency_weight: with a multi-hypothesis Q-Net, how much the agreement of
            each hypothesis' silhouette with the dense net's amodal mask counts in ranking
            them (soft IoU 0..1 times this, ``hypotheses``); 0: no mask term. Above 0 the
            dense net runs on every detection.
        refine: add the region-based refinement stage (``refinement.PoseRefiner``).
        refine_hypotheses: with refinement, how many of each detection's best-ranked
            rotation hypotheses are solved and refined (the best-scored is kept); each costs
            the screening iterations (accuracy by their number: docs/refinement.md).
        refine_min_score: with refinement, poses scored below this (0..1) are dropped.
        refine_prior_deg: with refinement, the standard deviation of a prior around each
            start's rotation, degrees; 0: none (``RefinerConfig.prior_rotation_deg``).
        refine_prior_mm: the same for the start's translation, millimetres; 0: none.
        refine_threads: threads the refinement's per-line loops run on; 0: one per core.
        refine_occlusions: the poses refined together hide each other's contour where one
            is nearer the camera (``RefinerConfig.model_occlusions``).
        refine_mask_choice_weight: where the dense net runs, how much each refined
            candidate's silhouette agreement (soft IoU 0..1) with its amodal mask counts
            beside the refinement score in choosing a detection's pose
            (``PoseRefiner.mask_choice_weight``); 0: the score alone. It does not make the
            dense net run.
        pose_source: where each detection's candidate poses come from: 'qnet' (Q-Net's
            hypotheses + the Bounding Box Equation, the paper's path), 'dense' (PnP over
            the dense net's correspondences, with PnP's or the equation's translation per
            ``dense_translation``), 'dense+qnet' (both; the refiner, or else the PnP pose
            when found, picks).
        dense_translation: 'pnp' or 'bbox_equation' (PnP's rotation, the equation's
            translation from the detector's box) or 'both' (two candidates).
        dense_mask: the predicted mask the refiner's region modality takes as the object's
            foreground: 'amodal', 'visible' or 'none' (the colours alone). The dense net
            runs when its poses are candidates or its mask is used.
        backend: what runs the networks, one of ``backends.BACKENDS``.
        precision: what the detector and Q-Net run as: 'fp32' (the float networks), 'int8'
            (the int8 graph beside each weight file, ``int8_graphs``; onnxruntime only) or
            'auto' (each network's int8 graph where the CPU has int8 dot-product
            instructions and a graph of those weights exists, else fp32).
        device: torch device, 'cpu', 'cuda' or 'cuda:N' (onnxruntime runs on the CPU only).
        threads: intra-op threads of the backend; 0: its default (one per core).

    Raises:
        InputError: 'field: reason' (or 'field / field: reason') for the first value, or
            combination, it does not take.

    """

    score_threshold: float = _option(0.3, 0.0, 1.0)
    max_instances: int = _option(1, 1, 100)
    box_consistency_weight: float = _option(DEFAULT_BOX_CONSISTENCY_WEIGHT, 0.0, 1000.0)
    mask_consistency_weight: float = _option(0.0, 0.0, 1000.0)
    refine: bool = _option(True)
    refine_hypotheses: int = _option(3, 1, 8)
    refine_min_score: float = _option(0.0, 0.0, 1.0)
    refine_prior_deg: float = _option(0.0, 0.0, 180.0)
    refine_prior_mm: float = _option(0.0, 0.0, 1000.0)
    refine_threads: int = _option(0, 0, 256)
    refine_occlusions: bool = _option(True)
    refine_mask_choice_weight: float = _option(8.0, 0.0, 1000.0)
    pose_source: str = _option('qnet', choices=POSE_SOURCES)
    dense_translation: str = _option('both', choices=DENSE_TRANSLATIONS)
    dense_mask: str = _option('none', choices=DENSE_MASKS)
    backend: str = _option('onnxruntime', choices=BACKENDS)
    precision: str = _option('auto', choices=PRECISIONS)
    device: str = _option('cpu')
    threads: int = _option(0, 0, 256)

    def __post_init__(self) -> None:
        for option in fields(self):
            check_option(option.name, getattr(self, option.name))
        if self.backend != 'torch' and self.device != 'cpu':
            raise InputError(f'backend / device: {self.backend} runs on the CPU only; use '
                             f'the torch backend for device {self.device}')
        if self.precision == 'int8' and self.backend != 'onnxruntime':
            raise InputError(f'precision / backend: the int8 graphs run on onnxruntime, not '
                             f'{self.backend}')

    @property
    def uses_qnet(self) -> bool:
        """Tell whether Q-Net's hypotheses are candidates."""
        return self.pose_source in ('qnet', 'dense+qnet')

    @property
    def uses_dense(self) -> bool:
        """Tell whether the dense net's PnP poses are candidates."""
        return self.pose_source in ('dense', 'dense+qnet')

    @property
    def runs_dense(self) -> bool:
        """Tell whether the dense net runs: for its PnP poses or its masks."""
        return self.uses_dense or (self.refine and self.dense_mask != 'none') or \
            self.ranks_by_mask

    @property
    def ranks_by_mask(self) -> bool:
        """Tell whether Q-Net's hypotheses are ranked by the dense net's amodal masks too."""
        return self.uses_qnet and self.mask_consistency_weight > 0.0

    @property
    def refiner_config(self) -> RefinerConfig:
        """Return the shipped RefinerConfig with these options' prior, threads, occlusions."""
        return RefinerConfig(prior_rotation_deg=self.refine_prior_deg,
                             prior_translation_m=self.refine_prior_mm / 1000.0,
                             threads=self.refine_threads,
                             model_occlusions=self.refine_occlusions)

    @property
    def candidates_per_detection(self) -> int:
        """Rotation hypotheses solved (and refined) per detection: 1 without refinement."""
        return self.refine_hypotheses if self.refine else 1


_FIELDS = {option.name: option for option in fields(PipelineOptions)}
_TYPES = {'bool': bool, 'int': int, 'float': float, 'str': str}


def option_range(name: str) -> tuple[float, float] | None:
    """Return the inclusive (low, high) of option ``name``, None when it has no range."""
    return _FIELDS[name].metadata['range']


def check_option(name: str, value: Any) -> None:
    """Raise InputError 'name: reason' when ``value`` is not one option ``name`` takes."""
    option = _FIELDS[name]
    expected = _TYPES[option.type]
    # bool is an int in Python; an int is a fine float; neither is accepted the other way.
    accepted = isinstance(value, expected) and not (expected is int and isinstance(value, bool))
    if expected is float:
        accepted = isinstance(value, (int, float)) and not isinstance(value, bool)
    if not accepted:
        raise InputError(f'{name}: {value!r} is not of type {option.type}')
    limits, choices = option.metadata['range'], option.metadata['choices']
    if limits is not None and not limits[0] <= value <= limits[1]:
        raise InputError(f'{name}: {value} is out of range [{limits[0]}, {limits[1]}]')
    if choices is not None and value not in choices:
        raise InputError(f'{name}: "{value}" is not one of {", ".join(choices)}')
    if name == 'device' and value != 'cpu' and not value.startswith('cuda'):
        raise InputError(f'{name}: "{value}" is not cpu, cuda or cuda:N')
