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
Stream mode's schedule: where a frame is detected, and by which route.

A camera slower than the full pipeline leaves it the time to run in the frame: where the
frame period (from the image stamps) exceeds ``STREAM_HEADROOM`` times the pipeline's run
time, no frame is handed to the background job; once no job runs, stream mode detects in
the frame itself, as tracking mode does, and answers with the frame's own detections instead
of poses carried over a large motion. So is a stream's first frame (no period known yet): a
single image is answered with its poses.

The routes (``stream_routes``): the pipeline of the options, and in stream mode with a
``tracking_in_place_pose_source`` other than ``pose_source`` a second, slower and more
accurate one (the in-place route) that detects instead where the period holds its run time
too (learned the same way; tried when not known yet, and again every
``IN_PLACE_RETRY_EVERY`` frames detected in place where it did not fit). Where the shipped
dense net cannot load for it, the in-place route gives way (``in_place_fallback``).

``StreamSchedule`` keeps the running means; ``PoseTracker`` (``tracking``) asks it and
keeps the tracking policy (follow, adopt, carry).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

from bbpose_ros.core.inference.options import PipelineOptions

# Stream mode detects in the frame itself where the frame period exceeds the full
# pipeline's run time this many times (a margin for the tracks' own refinement and jitter).
STREAM_HEADROOM = 1.25
# Weight of the newest frame period and pipeline run time in their running means (0..1).
STREAM_SMOOTHING = 0.2
# Stamp steps outside (0, this] seconds are not a frame period (a jump in the stream).
MAX_FRAME_PERIOD_S = 5.0
# Where the in-place pipeline measured too slow for the frame period, every this many frames
# detected in place try it again (a slow run may have been a passing load).
IN_PLACE_RETRY_EVERY = 10


def stream_routes(options: PipelineOptions) -> list[PipelineOptions]:
    """
    Return the options of each route the loader builds: ``options``, then the in-place one.

    The in-place route (``pose_source`` = ``tracking_in_place_pose_source``) is there in
    stream mode where it differs; it shares the stages, each route running those it uses.
    """
    routes = [options]
    if options.tracking_stream and options.tracking_in_place_pose_source != options.pose_source:
        routes.append(replace(options, pose_source=options.tracking_in_place_pose_source))
    return routes


def in_place_fallback(routes: Sequence[PipelineOptions], runs_dense: Sequence[bool],
                      dense_named: bool, error: Exception,
                      log: Callable[[str], None] | None
                      ) -> tuple[list[PipelineOptions], list[bool]] | None:
    """
    Return the routes (and whether each runs the dense net) left when the dense net fails.

    Only the in-place route gives way, and only with the shipped net (e.g. an object it was
    not trained on): a file the user names (``dense_named``) must load. None where the
    ``error`` stands; else ``log`` gets a line, and the frames detected in place take
    ``pose_source``.
    """
    if runs_dense[0] or dense_named:
        return None
    if log is not None:
        log(f'tracking_in_place_pose_source {routes[1].pose_source} needs the dense '
            f'net ({error}); the frames detected in place take pose_source '
            f'{routes[0].pose_source}')
    return list(routes[:1]), list(runs_dense[:1])


def running_mean(mean: float | None, value: float | None) -> float | None:
    """Return a running mean (None: none yet) moved towards ``value`` (None: kept)."""
    if value is None:
        return mean
    return value if mean is None else mean + STREAM_SMOOTHING * (value - mean)


class StreamSchedule:
    """
    The camera's frame period and the routes' run times, and what they decide (module doc).

    Args:
        has_in_place: an in-place route is there.

    """

    def __init__(self, has_in_place: bool) -> None:
        self.has_in_place = has_in_place
        self._last_frame: tuple[float, int | None] | None = None    # (stamp_s, index)
        self.frame_period_s: float | None = None        # running means, seconds
        self.pipeline_s: float | None = None
        self.in_place_s: float | None = None
        self._in_place_skipped = 0      # frames detected in place without it since it ran

    def reset(self) -> None:
        """Start a new stream: its period is learned again, the in-place route tried again."""
        # A new stream tries the in-place pipeline again (its one slow frame may be past).
        self._last_frame = self.frame_period_s = self.in_place_s = None

    def frame(self, stamp_s: float, frame_index: int | None) -> None:
        """Learn the frame period from a frame's stamp (seconds) and stream index (or None)."""
        self.frame_period_s = running_mean(self.frame_period_s,
                                           self._frame_step(stamp_s, frame_index))

    def pipeline_ran(self, seconds: float) -> None:
        """Learn the full pipeline's run time from one run."""
        self.pipeline_s = running_mean(self.pipeline_s, seconds)

    def in_place_ran(self, seconds: float) -> None:
        """Learn the in-place route's run time from one run."""
        self.in_place_s = running_mean(self.in_place_s, seconds)

    def _frame_step(self, stamp_s, frame_index):
        """Return the camera's seconds per frame since the previous call, None across a jump."""
        last, self._last_frame = self._last_frame, (stamp_s, frame_index)
        if last is None:
            return None
        frames = 1 if frame_index is None or last[1] is None else frame_index - last[1]
        if frames < 1 or not 0.0 < stamp_s - last[0] <= MAX_FRAME_PERIOD_S * frames:
            return None
        return (stamp_s - last[0]) / frames

    def camera_leaves_time(self) -> bool:
        """
        Tell whether the frame period holds the full pipeline with headroom.

        Before two stamps give a period (a stream's first frame; ``reset`` starts a new
        stream) it does: there is nothing to answer from but the frame itself.
        """
        return self.frame_period_s is None or self.pipeline_s is None or \
            self.frame_period_s > STREAM_HEADROOM * self.pipeline_s

    def takes_in_place(self) -> bool:
        """
        Tell whether the in-place route detects a frame in place (the camera leaving time).

        It does where the frame period holds its run time with headroom, or that is not
        known yet, or it was last tried ``IN_PLACE_RETRY_EVERY`` such frames ago (its run
        time is then measured afresh); not without an in-place route or a known period.
        """
        period = self.frame_period_s
        if not self.has_in_place or period is None:
            return False
        if self._in_place_skipped + 1 >= IN_PLACE_RETRY_EVERY:
            self.in_place_s = None          # measured afresh
        if self.in_place_s is None or period > STREAM_HEADROOM * self.in_place_s:
            self._in_place_skipped = 0
            return True
        self._in_place_skipped += 1
        return False
