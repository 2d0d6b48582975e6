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
Scoring a running node's recorded poses against a bag's ground truth (``replay-eval``).

The node publishes poses, not its detector's boxes: ground-truth and estimated poses are
matched through the projection of the object's mesh at each pose, then scored as ``bbpose
eval`` scores (``evaluation.score_frame``). A frame is a ``bags.reader.BagFrame`` (its
``stamp_ns``, ``camera`` and ``ground_truth``), a recording a ``cli.graph.replay.Recording``
(what the node answered, by image stamp).
"""

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from bbpose_ros.core.data.bop import GroundTruthInstance
from bbpose_ros.core.data.models import ObjectModel
from bbpose_ros.core.eval.evaluation import InstanceScore, pose_box, score_frame
from bbpose_ros.core.eval.evaluation import summarize_objects
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.latency import timing_summary
from bbpose_ros.core.pipeline.poses import Detection, PoseEstimate

RecordedPose = tuple[str, np.ndarray, np.ndarray]   # object name, rotation (3, 3), t (3,) m


def ground_truth_instances(frame: Any,
                           models: Mapping[str, ObjectModel]) -> list[GroundTruthInstance]:
    """Make GroundTruthInstances of a BagFrame's ground truth (configured objects only)."""
    instances = []
    for name, poses in frame.ground_truth.items():
        for rotation, translation in poses if name in models else ():
            box = pose_box(models[name], frame.camera, rotation, translation)
            instances.append(GroundTruthInstance(name, models[name].obj_id, rotation,
                                                 translation, box, box, 1.0))
    return instances


def node_estimates(entries: Sequence[RecordedPose], models: Mapping[str, ObjectModel],
                   camera: CameraIntrinsics) -> list[PoseEstimate]:
    """Make PoseEstimates of a frame's recorded (name, rotation, translation) poses."""
    return [PoseEstimate(Detection(name, 1.0, pose_box(models[name], camera, rotation,
                                                       translation)),
                         rotation, translation)
            for name, rotation, translation in entries]


def score_recording(frames: Sequence[Any], poses: Mapping[int, Sequence[RecordedPose]],
                    models: Mapping[str, ObjectModel]) -> dict[str, list[InstanceScore]]:
    """
    Score the node's poses per frame; returns {object name: [InstanceScore]}.

    ``poses``: {stamp: [(object name, rotation, translation)]}, a Recording's ``poses`` or
    ``detections``.
    """
    scores = {name: [] for name in models}
    for frame in frames:
        estimates = node_estimates(poses.get(frame.stamp_ns, []), models, frame.camera)
        for score in score_frame(models, ground_truth_instances(frame, models), estimates,
                                 frame.camera):
            scores[score.object_name].append(score)
    return scores


def latencies_ms(recording: Any) -> list[dict[str, float]]:
    """
    Return per-frame {stage: ms} of the graph round trip, from the image's publication.

    ``end_to_end``: to its last PoseStamped received (frames with poses); ``answer``: to its
    MarkerArray received (every answered frame).
    """
    latencies = []
    for stamp, sent_s in recording.published_s.items():
        arrivals = {'end_to_end': recording.pose_received_s.get(stamp),
                    'answer': recording.answered_s.get(stamp)}
        latencies.append({key: (arrival_s - sent_s) * 1e3
                          for key, arrival_s in arrivals.items() if arrival_s is not None})
    return latencies


def recording_report(recording: Any, scores: Mapping[str, Sequence[InstanceScore]],
                     detection_scores: Mapping[str, Sequence[InstanceScore]],
                     ) -> dict[str, Any]:
    """
    Make a replay's report: per-object and mean scores, node and graph timings, frames.

    ``scores``, ``detection_scores``: ``score_recording`` of the PoseStamped topics' poses
    and of the ~/detections ones. The report's ``detections`` holds the latter's mean, how
    many arrays and detections arrived, and how many /tf transforms.
    """
    report = summarize_objects(scores)
    report['timing_ms'] = dict(recording.timings_ms)
    report['timing_ms'].update(timing_summary(latencies_ms(recording)))
    report['frames'] = {'sent': len(recording.published_s),
                        'answered': len(recording.answered_s)}
    report['detections'] = {
        'mean': summarize_objects(detection_scores)['mean'],
        'arrays': len(recording.detections),
        'detections': sum(len(entries) for entries in recording.detections.values()),
        'tf_transforms': sum(recording.transforms.values())}
    return report
