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
Which of the teacher's poses become labels: gates measured for precision on the dev frames.

Each pose of each frame gets one verdict, tried in this order:

1. ``detection``: the detector scored it under ``min_detection_score``: not a label, and
   its box is an ignore region (neither object nor background to the students).
2. ``confidence``: its refinement score is under its object's threshold this round: the
   ``keep`` quantile of that object's scores over the recording, and never under
   ``min_confidence`` (thresholds set per object and round from the distribution, as
   Chen et al. do: an object the teacher is unsure of gets fewer labels, not worse ones).
   An ignore region too.
3. ``box``: the box its mesh projects to at the pose overlaps the detector's box by less
   than ``min_box_iou``: the refinement moved it far from what was detected. Ignored.
4. ``consistency``: in a static scene the distance between two objects' centres does not
   change as the camera moves; a pose whose distances to the other confident poses of its
   frame disagree with their median over the recording by more than ``consistency_mm``
   for most of them is refused (ignored). Off with ``consistency_mm`` 0 (a scene whose
   objects move).

What passes is ``accepted``: a label of its amodal box (for the detector) and its rotation
(for Q-Net).
"""

from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from itertools import combinations

import numpy as np

from bbpose_ros.core.adaptation.adapt_settings import SelectionSettings
from bbpose_ros.core.adaptation.teacher import TeacherPose
from bbpose_ros.core.geometry.boxes import box_iou

VERDICTS = ('accepted', 'detection', 'confidence', 'box', 'consistency')
# Frames two objects must share before their centre distance is judged.
MIN_PAIR_FRAMES = 3


@dataclass(frozen=True)
class Verdict:
    """A teacher pose with the verdict of ``select_labels`` (one of VERDICTS)."""

    pose: TeacherPose
    verdict: str

    @property
    def accepted(self) -> bool:
        """Tell whether the pose is a label."""
        return self.verdict == 'accepted'


def confidence_thresholds(frames: Mapping[str, Sequence[TeacherPose]],
                          settings: SelectionSettings) -> dict[str, float]:
    """{object: the lowest confidence a label of it needs} over the detections trusted."""
    scores = defaultdict(list)
    for poses in frames.values():
        for pose in poses:
            if pose.detection_score >= settings.min_detection_score:
                scores[pose.object_name].append(pose.confidence)
    return {name: max(settings.min_confidence,
                      float(np.quantile(values, 1.0 - settings.keep)))
            for name, values in scores.items()}


def select_labels(frames: Mapping[str, Sequence[TeacherPose]],
                  settings: SelectionSettings) -> dict[str, list[Verdict]]:
    """
    Judge every teacher pose of a recording (module docstring).

    Args:
        frames: {frame key: the teacher's poses of that frame}, the whole recording.
        settings: SelectionSettings.

    Returns:
        {frame key: [Verdict], in the poses' order}.

    """
    thresholds = confidence_thresholds(frames, settings)
    verdicts = {}
    for key, poses in frames.items():
        verdicts[key] = []
        for pose in poses:
            if pose.detection_score < settings.min_detection_score:
                verdict = 'detection'
            elif pose.confidence < thresholds[pose.object_name]:
                verdict = 'confidence'
            elif box_iou(pose.box_uv, pose.detection_box_uv)[0, 0] < settings.min_box_iou:
                verdict = 'box'
            else:
                verdict = 'accepted'
            verdicts[key].append(Verdict(pose, verdict))
    if settings.consistency_mm > 0.0:
        verdicts = _consistency(verdicts, settings.consistency_mm / 1000.0)
    return verdicts


def _consistency(verdicts, tolerance_m):
    """Refuse accepted poses whose centre distances to most partners break the median."""
    distances = defaultdict(dict)       # (a, b) -> {frame: centre distance, metres}
    for key, judged in verdicts.items():
        accepted = {v.pose.object_name: v.pose for v in judged if v.accepted}
        for a, b in combinations(sorted(accepted), 2):
            distances[a, b][key] = float(np.linalg.norm(accepted[a].translation -
                                                        accepted[b].translation))
    medians = {pair: float(np.median(list(by_frame.values())))
               for pair, by_frame in distances.items() if len(by_frame) >= MIN_PAIR_FRAMES}
    result = {}
    for key, judged in verdicts.items():
        result[key] = []
        for verdict in judged:
            name = verdict.pose.object_name
            votes = [abs(by_frame[key] - medians[pair]) <= tolerance_m
                     for pair, by_frame in distances.items()
                     if name in pair and key in by_frame and pair in medians]
            if verdict.accepted and votes and np.mean(votes) < 0.5:
                verdict = Verdict(verdict.pose, 'consistency')
            result[key].append(verdict)
    return result


def verdict_counts(verdicts: Mapping[str, Sequence[Verdict]]) -> dict[str, dict[str, int]]:
    """{object: {verdict: count}} over a recording (``report.json``)."""
    counts = defaultdict(lambda: dict.fromkeys(VERDICTS, 0))
    for judged in verdicts.values():
        for verdict in judged:
            counts[verdict.pose.object_name][verdict.verdict] += 1
    return {name: counts[name] for name in sorted(counts)}
