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
Every setting of a network's training run, declared once.

``TrainSettings`` declares the settings all four runs share (batch, rate, weight decay,
visibility floor, held-out share, augmentation), ``TrunkTrainSettings`` adds the trunk's
rate of the three networks that start from ImageNet, and each stage's class adds its own
settings and sets its defaults of the shared ones (``stage_settings``). Each field is one
setting under one name from the ``bbpose train`` option (``--name-with-dashes``, generated
by ``cli/settings_options.py`` from the declarations, ``util.declarations``) to the weight
file's ``training.settings`` record: its type, default, range or choices and a one-line
description live here and nowhere else. A settings object checks its values when it is made
(``check_settings``), wherever they come from.

The fits of output layers on cached features (``object_rows.fit_new_rows``,
``adaptation.students``) declare theirs here too: ``FeatureTraining`` the settings both
share, ``RowTraining`` (add-object's new rows) and ``HeadTraining`` (adapt's detector
heads) what each adds, the latter with its own defaults (``redeclared``).

A leaf module: it imports nothing but ``util``, so the ``bbpose train`` parsers load
without torch.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, fields
from typing import Any

from bbpose_ros.core.util.declarations import check_settings, redeclared, setting

AUGMENT_STYLES = ('basic', 'strong')
HEATMAP_MODES = ('none', 'bias', 'all')


@dataclass
class TrainSettings:
    """
    Settings every network's training run shares; a stage's class adds its own.

    Each field's description is in its declaration below (``declared`` lists them with
    their types, ranges and choices). All are recorded in the weight file.

    Raises:
        InputError: 'name: reason' for the first value it does not take.

    """

    batch: int = setting(
        32, 'Samples per training step: scenes (windows of them) for the detector, crops '
        'for the others.', low=1)
    lr: float = setting(1e-3, 'Peak learning rate of the cosine schedule.', low=0.0)
    weight_decay: float = setting(1e-4, "AdamW's weight decay.", low=0.0)
    min_visib: float = setting(
        0.1, 'Instances less visible than this share are not trained on.', low=0.0, high=1.0)
    val_fraction: float = setting(
        0.05, 'Share of the cache held out for validation: its last scenes or crops, never '
        'trained on.', low=0.0, high=1.0)
    augment: str = setting(
        'basic', 'Photometric augmentation of the training batches: basic (brightness, contrast, '
        'colour gains, noise) or strong (also blur, sharpening, saturation, grey, JPEG).',
        choices=AUGMENT_STYLES)
    augment_strength: float = setting(
        1.0, "Scale of the augmentation's perturbations and probabilities; 0: none.", low=0.0)

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass
class TrunkTrainSettings(TrainSettings):
    """The settings of a run whose network starts from an ImageNet trunk ('lite0')."""

    trunk_lr_scale: float = setting(
        0.1, "The pretrained trunk's learning rate / the rest's ('lite0' backbone); 0 "
        'freezes it.', low=0.0)


def stage_settings(**defaults: Any) -> Callable[[type], type]:
    """
    Make a stage's settings class: ``defaults`` ({name: value}) for settings it inherits.

    The class derives from TrainSettings or TrunkTrainSettings and declares its own
    settings with ``setting``; an inherited setting keeps its declaration (description,
    range, place in the record) and takes the stage's default.
    """
    def make(cls: type) -> type:
        inherited = {declaration.name: declaration for declaration in fields(cls)}
        annotations = dict(cls.__dict__.get('__annotations__', {}))
        for name, value in defaults.items():
            if name not in inherited:
                raise TypeError(f'{cls.__name__}: no inherited setting {name!r}')
            annotations[name] = inherited[name].type
            setattr(cls, name, field(default=value, metadata=inherited[name].metadata))
        cls.__annotations__ = annotations
        return dataclass(cls)
    return make


@stage_settings(batch=16, lr=2e-3)
class DetectorTrainSettings(TrunkTrainSettings):
    """Settings of a detector run (``detector_training``)."""

    box_weight: float = setting(
        1.0, 'Weight of the L1 on the log box sides beside the heatmap focal loss.', low=0.0)
    train_crop: tuple[int, int] = setting(
        (192, 160), 'Training window (width, height) in input pixels, multiples of 16, cut '
        'at random from each cached frame.', metavar='W,H')


@stage_settings(batch=64, min_visib=0.2)
class QNetTrainSettings(TrunkTrainSettings):
    """Settings of a Q-Net run (``qnet_training``)."""

    box_sigma: float = setting(
        0.05, 'Crop jitter: per-side box error / box size, as a detector errs (its '
        "validation's side_sigma).", low=0.0)
    sign_invariant: bool = setting(
        False, 'Loss (1 - |q . q_gt|) / 2: q and -q are one rotation; false: the hemisphere '
        'rule alone.')
    max_inplane_deg: float | None = setting(
        None, 'Train only on crops rolled at most this much about the optical axis, degrees '
        '(an upright-object prior); none: all.', low=0.0, high=180.0)


@stage_settings(batch=32, min_visib=0.15)
class DenseTrainSettings(TrunkTrainSettings):
    """Settings of a dense net run (``dense_training``)."""

    coordinate_weight: float = setting(
        1.0, 'Weight of the coordinate L1 beside the mask BCEs.', low=0.0)
    frozen_blocks: int = setting(
        5, "Trunk blocks (after the stem) kept at ImageNet's weights (5: strides 2 to 8).",
        low=0, high=16)


@stage_settings(batch=256, lr=2e-3, val_fraction=0.1)
class VerifierTrainSettings(TrainSettings):
    """Settings of a run of the detector's second stage (``verifier_training``)."""

    mined_per_class: int = setting(
        10, "Highest peaks of each class's heatmap mined as candidates per scene.", low=1)
    positive_iou: float = setting(
        0.3, 'A candidate overlapping a true box by at least this IoU is a positive of its '
        'class.', low=0.0, high=1.0)
    box_sigma: float = setting(
        0.06, 'Jitter of the true boxes added as positives: per-side error / box size.',
        low=0.0)
    positive_fraction: float = setting(
        0.375, 'Share of each batch drawn from the positives (candidates on an object).',
        low=0.0, high=1.0)
    label_smoothing: float = setting(
        0.05, "Label smoothing of the classifier's cross-entropy.", low=0.0, high=1.0)
    box_weight: float = setting(
        5.0, "Weight of the smooth L1 of the positives' side corrections beside the "
        'cross-entropy.', low=0.0)


@dataclass(frozen=True)
class FeatureTraining:
    """
    How output layers learn on cached features: what every such fit shares.

    The shared layers run once over ``passes`` augmented copies of each training input, and
    the layers fitted learn from those features (``object_rows.fit_new_rows``). Each
    field's description is in its declaration; all are recorded in the weight file.

    Raises:
        InputError: 'name: reason' for the first value it does not take.

    """

    steps: int = setting(
        2000, 'Adam steps on the cached features (cosine rate, warmup steps of warm-up).')
    batch: int = setting(32, 'Cached inputs (frames or crops) per step.')
    lr: float = setting(1e-2, 'Peak learning rate.')
    passes: int = setting(
        2, 'Augmented copies of each training input whose features are cached.')
    warmup: int = setting(100, 'Warm-up steps of the rate.')

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass(frozen=True)
class RowTraining(FeatureTraining):
    """
    How a network's new rows learn (``object_rows.fit_new_rows``; in the weight file).

    Rows fitted to renders carry to real frames with a spread from run to run that averaging
    over ``seeds`` narrows.
    """

    seeds: int = setting(
        1, 'Independent runs from the same start on the same cached features, each with its '
        'own batch draws; the new rows are their average.', low=1)


@dataclass(frozen=True)
class HeadTraining(FeatureTraining):
    """How the detector's heads learn (``adaptation.students``; in the weight file)."""

    steps: int = redeclared(FeatureTraining, 'steps', 400)
    batch: int = redeclared(FeatureTraining, 'batch', 8)
    lr: float = redeclared(FeatureTraining, 'lr', 1e-3)
    passes: int = redeclared(FeatureTraining, 'passes', 4)
    warmup: int = redeclared(FeatureTraining, 'warmup', 50)
    anchor: float = setting(
        1.0, 'Weight of the squared distance of the heads to their start values.')
    box_weight: float = setting(
        1.0, "Weight of the box sides' L1 beside the heatmap's focal loss.")
    heatmap: str = setting(
        'none', "What of the heatmap head learns: 'none', 'bias' (one threshold per object) "
        "or 'all'; the box head always learns.", choices=HEATMAP_MODES)
