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
What ``bbpose adapt`` runs, declared once: its rounds, the gates of each, the students.

``SelectionSettings`` are the gates of ``selection.select_labels``, ``AdaptSettings``
the whole run's settings (recorded in ``report.json`` and ``inputs.json``), with the
students' ``HeadTraining`` and ``RowTraining`` (``training.settings``) nested. Each field
is a setting (``util.declarations``), described in its declaration and checked when the
object is made.

A leaf module: it imports nothing but ``util`` and ``training.settings``, so the ``bbpose
adapt`` parser loads without torch.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from bbpose_ros.core.training.settings import HeadTraining, RowTraining
from bbpose_ros.core.util.declarations import above_zero, check_settings, nested, setting


@dataclass(frozen=True)
class SelectionSettings:
    """
    The gates of ``select_labels`` (recorded in ``report.json``).

    Each field is a setting (``util.declarations``), described in its declaration and checked
    when the object is made.
    """

    min_detection_score: float = setting(
        0.3, 'Lowest detector score of a label.', low=0.0, high=1.0)
    keep: float = setting(
        0.5, "Share of each object's poses over the recording a round keeps, by confidence "
        '(above 0).', low=0.0, high=1.0, check=above_zero)
    min_confidence: float = setting(
        0.6, 'Lowest refinement score of a label whatever keep.', low=0.0, high=1.0)
    min_box_iou: float = setting(
        0.5, "Lowest IoU between the detector's box and the pose's projected box.",
        low=0.0, high=1.0)
    consistency_mm: float = setting(
        60.0, 'Largest change of a centre distance across frames, millimetres; 0: no '
        'consistency gate.', low=0.0)

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass(frozen=True)
class AdaptSettings:
    """
    What the adaptation runs (recorded in ``report.json`` and ``inputs.json``).

    Besides its settings: ``selection``, the other gates (its ``keep`` replaced per round);
    ``detector``, the HeadTraining of the detector's heads; ``qnet``, the RowTraining of
    Q-Net's head rows.

    Raises:
        InputError: 'name: reason' for the first value it does not take.

    """

    rounds: int = setting(
        2, "Teacher-students rounds; each later round's teacher runs the previous round's "
        'students.', low=1, high=3)
    keep_per_round: tuple[float, ...] = setting(
        (0.5, 0.7), "Share of each object's confident poses a round keeps (SelectionSettings' "
        'keep), one per round; the last repeats.', low=0.0, high=1.0, metavar='SHARE,...',
        check=above_zero)
    selection: SelectionSettings = nested(SelectionSettings)
    teacher_threshold: float = setting(
        0.1, "Lowest detector score the teacher refines; poses under the selection's "
        'min_detection_score only mark ignore regions.', low=0.0, high=1.0)
    detector: HeadTraining = nested(HeadTraining)
    qnet: RowTraining = nested(lambda: RowTraining(steps=400, batch=32, lr=1e-3, passes=4,
                                                   warmup=50))
    seed: int = setting(0, "Seed of the students' draws.")
    map_labels: bool = setting(
        False, "Where the frames carry the camera's pose (a bag's /tf, BOP's cam_R_w2c), "
        "label with the map of each static scene: the teacher's poses fused over the views.")

    def __post_init__(self) -> None:
        check_settings(self)

    def selection_of(self, round_number: int) -> SelectionSettings:
        """Return the gates of round ``round_number`` (1-based)."""
        keep = self.keep_per_round[min(round_number, len(self.keep_per_round)) - 1]
        return replace(self.selection, keep=keep)
