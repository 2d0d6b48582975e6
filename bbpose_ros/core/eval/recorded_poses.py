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
eval`` scores (``instance_scores.score_frame``). A frame is any ``GroundTruthFrame`` (a
``bags.reader.BagFrame``); a ``Recording`` holds what the node answered, by image stamp
(``cli.graph.replay.Recorder`` fills it).
"""

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import numpy as np

from bbpose_ros.core.data.bop import GroundTruthInstance
from bbpose_ros.core.data.models import ObjectModel
from bbpose_ros.core.eval.instance_scores import InstanceScore, score_frame, summarize_objects
from bbpose_ros.core.eval.matching import pose_box
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.rigid import invert_rigid
from bbpose_ros.core.pipeline.latency import timing_summary
from bbpose_ros.core.pipeline.poses import Detection, PoseEstimate

RecordedPose = tuple[str, np.ndarray, np.ndarray]   # object name, rotation (3, 3), t (3,) m


class GroundTruthFrame(Protocol):
    """
    A recorded frame's ground truth, as a bag gives it (``bags.reader.BagFrame``).

    Attributes:
        stamp_ns: header stamp of the image, nanoseconds.
        camera: intrinsics of the image (None: the bag had no CameraInfo; such a frame
            cannot be scored).
        ground_truth: {object name: [(rotation (3, 3), translation (3,) metres), ...]}.

    """

    stamp_ns: int
    camera: CameraIntrinsics | None
    ground_truth: Mapping[str, Sequence[tuple[np.ndarray, np.ndarray]]]


@dataclass
class Recording:
    """
    What the node answered, by image stamp (ns); times are time.perf_counter() seconds.

    Attributes:
        published_s: {stamp: when the image was published}.
        answered_s: {stamp: when its MarkerArray arrived}.
        poses: {stamp: [(object name, rotation (3, 3), translation (3,) metres)]}.
        pose_received_s: {stamp: when its last PoseStamped arrived}.
        detections: {stamp: [(class id, rotation (3, 3), translation (3,) metres)]} of its
            Detection3DArray (an empty list: an array without detections).
        map_detections: the same of its ~/map/detections, in its ``fixed_frame``.
        transforms: {stamp: number of /tf transforms}.
        timings_ms: the node's stage latencies from its last diagnostics:
            {stage: {'median', 'p95'}}.
        counts: the node's frame counters from its last diagnostics.
        messages: [(topic, type name, receive time ns, raw CDR)] for the results bag.

    """

    published_s: dict[int, float] = field(default_factory=dict)
    answered_s: dict[int, float] = field(default_factory=dict)
    poses: dict[int, list[RecordedPose]] = field(default_factory=dict)
    pose_received_s: dict[int, float] = field(default_factory=dict)
    detections: dict[int, list[RecordedPose]] = field(default_factory=dict)
    map_detections: dict[int, list[RecordedPose]] = field(default_factory=dict)
    transforms: dict[int, int] = field(default_factory=dict)
    timings_ms: dict[str, dict[str, float]] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)
    messages: list[tuple[str, str, int, bytes]] = field(default_factory=list)


def ground_truth_instances(frame: GroundTruthFrame,
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


def score_recording(frames: Sequence[GroundTruthFrame],
                    poses: Mapping[int, Sequence[RecordedPose]],
                    models: Mapping[str, ObjectModel]) -> dict[str, list[InstanceScore]]:
    """
    Score the node's poses per frame; returns {object name: [InstanceScore]}.

    ``poses``: {stamp: [(object name, rotation, translation)]}, a Recording's ``poses`` or
    ``detections``. Each score's key is '<image stamp, ns>/<index in the frame's ground
    truth>': two replays of one bag pair instance by instance (``bbpose compare``).
    """
    scores = {name: [] for name in models}
    for frame in frames:
        estimates = node_estimates(poses.get(frame.stamp_ns, []), models, frame.camera)
        for k, score in enumerate(score_frame(models, ground_truth_instances(frame, models),
                                              estimates, frame.camera)):
            scores[score.object_name].append(replace(score, key=f'{frame.stamp_ns}/{k}'))
    return scores


def map_in_cameras(frames: Sequence[GroundTruthFrame],
                   map_poses: Mapping[int, Sequence[RecordedPose]]
                   ) -> dict[int, list[RecordedPose]]:
    """
    Carry the node's map poses (fixed frame) of each frame into its camera frame.

    ``frames``: BagFrames with ``world_from_camera`` (the bag's /tf); a frame without one,
    or without a map message, gets no poses.
    """
    carried = {}
    for frame in frames:
        world_from_camera = getattr(frame, 'world_from_camera', None)
        if world_from_camera is None or frame.stamp_ns not in map_poses:
            continue
        camera_from_world = invert_rigid(world_from_camera)
        carried[frame.stamp_ns] = [
            (name, camera_from_world[:3, :3] @ rotation,
             camera_from_world[:3, :3] @ translation + camera_from_world[:3, 3])
            for name, rotation, translation in map_poses[frame.stamp_ns]]
    return carried


def latencies_ms(recording: Recording) -> list[dict[str, float]]:
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


def recording_report(recording: Recording, scores: Mapping[str, Sequence[InstanceScore]],
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
