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
Tracking over a stream: each refined pose seeds the next frame's refinement.

Policy, per frame:

1. every track is refined from its last pose with its own colour model (a few iterations:
   the motion between frames is small); a track scored below ``tracking_min_score`` is
   lost;
2. the full pipeline (detector, Q-Net, Bounding Box Equation, refinement) runs when there
   are no tracks, when a track was lost in this frame, or every
   ``tracking_redetect_every`` frames (new objects may have come into view);
3. a detection of an object that is already tracked replaces the track only when its
   refinement scores higher; other detections scored at least ``tracking_min_score`` start
   tracks, the rest are reported for this frame only.

Both settings are the pipeline's PipelineOptions'.

In stream mode (``tracking_stream``) no frame waits for the full pipeline: step 1 answers
every frame, and where step 2 asks for detection the frame is handed to a
``BackgroundDetection``, which runs the full pipeline in a thread of its own on the newest
frame handed (while a frame waits there, each newer one replaces it). The poses of a
finished job are adopted at the start of the next frame as in step 3, before step 1, whose
refinement carries them from their frame to the current one; poses that start no track are
carried the same way and reported in that frame only (those that fail are dropped). A
frame's timings then carry the adopted job's ``stream_job`` (how long the full pipeline
ran) and ``stream_age`` (how old its poses are when adopted: from their frame's handing
over to the adoption), milliseconds.

Where a frame is detected (handed on, or in the frame itself where the camera leaves the
full pipeline the time) and by which route (``in_place``: the loader's
``tracking_in_place_pose_source`` route, slower and more accurate) is stream mode's schedule,
``stream_schedule.StreamSchedule``, learned from the image stamps and the routes' run times.

Tracks are per object name: one instance of each object is tracked (with ``max_instances``
above 1, the other detections of a tracked object are not reported while it is tracked).
Only objects the refiner has a viewpoint model of are tracked.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
import time
from typing import TYPE_CHECKING

import numpy as np

from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.pipeline.background_detection import BackgroundDetection
from bbpose_ros.core.pipeline.latency import StageTimer
from bbpose_ros.core.pipeline.pose_pipeline import PosePipeline
from bbpose_ros.core.pipeline.poses import FrameResult, PoseEstimate
from bbpose_ros.core.pipeline.refinement import PoseRefiner
from bbpose_ros.core.pipeline.stream_schedule import StreamSchedule
from bbpose_ros.core.refine.color_histograms import ColorHistograms
from bbpose_ros.core.util.errors import InputError

if TYPE_CHECKING:
    from bbpose_ros.core.data.models import ObjectModel


# Correspondence iterations of a tracking refinement (the refiner's last scales and
# standard deviations are used).
TRACK_ITERATIONS = 3
# How far a track's colour model moves towards each frame's (0..1).
TRACK_COLOR_RATE = 0.2


@dataclass
class Track:
    """One tracked object: its last pose and the colour model learned over frames."""

    pose: PoseEstimate
    histograms: ColorHistograms | None = field(default=None, repr=False)


class PoseTracker:
    """
    Runs a PosePipeline (with a refiner) over a stream, tracking refined poses.

    Args:
        pipeline: a PosePipeline with detector, rotation estimator and refiner; the
            tracker reads its ``options``' ``tracking_*`` settings.
        in_place: in stream mode, a pipeline (the same refiner) for the frames detected in
            the frame itself where the camera's period holds its run time; None: ``pipeline``.

    """

    def __init__(self, pipeline: PosePipeline, in_place: PosePipeline | None = None) -> None:
        if not isinstance(pipeline.refiner, PoseRefiner):
            raise InputError('tracking needs a pipeline with a PoseRefiner')
        if in_place is not None and in_place.refiner is not pipeline.refiner:
            raise InputError('the in-place pipeline must share the tracked refiner')
        self.pipeline = pipeline
        self.in_place = in_place
        self.tracks: dict[str, Track] = {}
        self._since_detection = 0
        self._background = BackgroundDetection(pipeline) \
            if pipeline.options.tracking_stream else None
        self._schedule = StreamSchedule(in_place is not None)

    @property
    def options(self) -> PipelineOptions:
        """Return the pipeline's PipelineOptions, the tracker's settings among them."""
        return self.pipeline.options

    @property
    def models(self) -> dict[str, ObjectModel]:
        """Return the pipeline's {name: ObjectModel}: a tracker stands in for its pipeline."""
        return self.pipeline.models

    @property
    def background_running(self) -> bool:
        """Tell whether stream mode's background thread is alive."""
        return self._background is not None and self._background.running

    def reset(self) -> None:
        """Forget all tracks (a new camera, a jump back in time); stop a background job."""
        if self._background is not None:
            self._background.stop()
        self.tracks.clear()
        self._since_detection = 0
        self._schedule.reset()

    def close(self) -> None:
        """Reset and stop for good: later frames are answered by the tracks alone."""
        if self._background is not None:
            self._background.close()
        self.reset()

    def estimate(self, image_rgb: np.ndarray, camera: CameraIntrinsics,
                 stamp_s: float | None = None, frame_index: int | None = None
                 ) -> FrameResult:
        """
        Track, detect when the policy says so, and return the frame's poses.

        ``stamp_s``: the image's capture time, seconds (its header stamp), and
        ``frame_index``: its place in the camera's stream, frames dropped before this call
        included (None: the frame follows the previous one), from which stream mode learns
        the camera's frame period; None: the time of this call. In stream mode
        ``image_rgb`` may be read by the background job after this returns: the caller
        must not write to it afterwards.
        """
        if self._background is not None:
            return self._stream(image_rgb, camera,
                                time.perf_counter() if stamp_s is None else stamp_s,
                                frame_index)
        timer = StageTimer()
        tracked = bool(self.tracks)
        lost = self._follow_tracks(image_rgb, camera)
        timer.lap('tracking' if tracked else None)
        self._since_detection += 1
        untracked = []
        if not self.tracks or lost or \
                self._since_detection >= self.options.tracking_redetect_every:
            untracked = self._detect_here(image_rgb, camera, timer)
        return FrameResult([track.pose for track in self.tracks.values()] + untracked,
                           timer.total())

    def _stream(self, image_rgb, camera, stamp_s, frame_index):
        """Stream mode: adopt the finished job's poses, track, detect (here or beside)."""
        timer = StageTimer()
        self._schedule.frame(stamp_s, frame_index)
        untracked = []
        finished = self._background.take()
        if finished is not None:
            if finished.error is not None:
                raise finished.error
            self._schedule.pipeline_ran(finished.run_ms * 1e-3)
            untracked = self._adopt(finished.result.poses)
            timer.timings_ms.update(stream_job=finished.run_ms,
                                    stream_age=(timer.start_s - finished.handed_s) * 1e3)
        tracked = bool(self.tracks or untracked)
        lost = self._follow_tracks(image_rgb, camera)
        untracked = self._carry(image_rgb, camera, untracked)
        timer.lap('tracking' if tracked else None)
        self._since_detection += 1
        if self._background.waiting or not self.tracks or lost or \
                self._since_detection >= self.options.tracking_redetect_every:
            if not self._schedule.camera_leaves_time():
                self._background.hand(image_rgb, camera)
                self._since_detection = 0
            elif self._background.idle:     # else the job in hand ends before long
                in_place = self.in_place if self._schedule.takes_in_place() else None
                untracked = self._detect_here(image_rgb, camera, timer, in_place)
                self._background.take()     # a job that ended meanwhile is older: dropped
        return FrameResult([track.pose for track in self.tracks.values()] + untracked,
                           timer.total())

    def _detect_here(self, image_rgb, camera, timer, pipeline=None):
        """Detect here by ``pipeline`` (default ``self.pipeline``); return the untracked poses."""
        if pipeline is None:
            pipeline = self.pipeline
        result = pipeline.estimate(image_rgb, camera)
        seconds = result.timings_ms['total'] * 1e-3
        if pipeline is self.pipeline:
            self._schedule.pipeline_ran(seconds)
        else:
            self._schedule.in_place_ran(seconds)
        timer.timings_ms.update((stage, ms) for stage, ms in result.timings_ms.items()
                                if stage != 'total')
        self._since_detection = 0
        return self._adopt(result.poses)

    def _follow_tracks(self, image_rgb, camera):
        """Refine every track from its last pose; drop the lost ones; tell if any was."""
        if not self.tracks:
            return False
        names = list(self.tracks)
        tracks = [self.tracks[name] for name in names]
        results = self.pipeline.refiner.refine_tracks(
            image_rgb, camera, names, [t.pose.rotation for t in tracks],
            [t.pose.translation for t in tracks], [t.histograms for t in tracks],
            TRACK_ITERATIONS)
        lost = False
        for name, track, result in zip(names, tracks, results):
            if not result.ok or result.score < self.options.tracking_min_score:
                del self.tracks[name]
                lost = True
                continue
            histograms = result.histograms if track.histograms is None else \
                track.histograms.blended(result.histograms, TRACK_COLOR_RATE)
            self.tracks[name] = Track(replace(track.pose, rotation=result.rotation,
                                              translation=result.translation,
                                              refinement_score=result.score), histograms)
        return lost

    def _carry(self, image_rgb, camera, poses):
        """Carry poses of an earlier frame to this one (stream mode); drop those that fail."""
        refiner = self.pipeline.refiner
        moving = [p for p in poses if p.object_name in refiner.viewpoint_models]
        if not moving:
            return list(poses)
        results = refiner.refine_tracks(
            image_rgb, camera, [p.object_name for p in moving], [p.rotation for p in moving],
            [p.translation for p in moving], [None] * len(moving), TRACK_ITERATIONS)
        carried = [p for p in poses if p.object_name not in refiner.viewpoint_models]
        return carried + [replace(p, rotation=r.rotation, translation=r.translation,
                                  refinement_score=r.score)
                          for p, r in zip(moving, results) if r.ok]

    def _adopt(self, poses):
        """Start or replace tracks with detected poses; return those of untracked objects."""
        untracked = []
        for pose in poses:
            current = self.tracks.get(pose.object_name)
            if current is not None:
                if pose.confidence > current.pose.confidence:
                    self.tracks[pose.object_name] = Track(pose)
            elif (pose.confidence >= self.options.tracking_min_score
                  and pose.object_name in self.pipeline.refiner.viewpoint_models):
                self.tracks[pose.object_name] = Track(pose)
            else:
                untracked.append(pose)
        return untracked
