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
The worker thread: the pipeline run on the newest paired frame, its results published.

Pairs wait in a one-item slot (``LatestSlot``): one that arrives while the worker
is busy replaces the one waiting (``superseded``) instead of queueing. The pipeline is
taken once per frame, so a run-time rebuild swaps it between two frames; a frame of a new
stream (the image stamps went back) resets a tracker first. A frame whose estimate fails is
counted and logged (``failed``), and the worker goes on with the next. A compressed frame
(``image_transport: compressed``) is decoded here, off the executor, and only when taken
(``decode``: ``FrameIntake.decode``); its decode time is the ``image_decode`` stage.
"""

from collections.abc import Callable
import threading
import time

from rclpy.context import Context
from rclpy.impl.rcutils_logger import RcutilsLogger
from sensor_msgs.msg import CameraInfo

from bbpose_ros.core.data.stamps import stamp_to_ns
from bbpose_ros.core.geometry.camera_info import CameraModel, Rectifier
from bbpose_ros.core.pipeline.tracking import PoseTracker
from bbpose_ros.core.util.latest_slot import LatestSlot
from bbpose_ros.ros.diagnostics import NodeStats
from bbpose_ros.ros.frame import Frame, stamp_text
from bbpose_ros.ros.node_pipeline import NodePipeline
from bbpose_ros.ros.publishers import FramePublishers
from bbpose_ros.ros.scene_mapping import SceneMapping
from bbpose_ros.ros.throttle import ProblemLog

# A stop waits this long for the worker to finish the frame in hand (one frame's work).
WORKER_JOIN_TIMEOUT_S = 5.0


class FrameWorker:
    """
    Runs the pipeline on the newest (Frame, CameraModel) pair in a thread of its own.

    Args:
        pipeline: returns the NodePipeline in use (a rebuild may swap it).
        publishers: what the results of a frame are published through.
        stats: counts answered and superseded frames, records their latencies.
        problems: counts and logs a failed estimate.
        logger: the node's logger.
        context: the node's context; once it is shut down a failure is not reported.
        decode: decodes a compressed Frame and makes its CameraModel from its CameraInfo;
            None when the frame is dropped (counted and logged by it).
        mapping: takes each answered frame's poses into the map (with ``fixed_frame``).

    """

    def __init__(self, pipeline: Callable[[], NodePipeline | None],
                 publishers: FramePublishers, stats: NodeStats, problems: ProblemLog,
                 logger: RcutilsLogger, context: Context,
                 decode: Callable[[Frame, CameraInfo], tuple[Frame, CameraModel] | None],
                 mapping: SceneMapping) -> None:
        self._pipeline = pipeline
        self._publishers = publishers
        self._stats = stats
        self._problems = problems
        self._logger = logger
        self._context = context
        self._decode = decode
        self._mapping = mapping
        self._slot = LatestSlot()
        self._thread: threading.Thread | None = None
        self._rectifier = Rectifier()             # its maps are kept from frame to frame

    def start(self, stream: int) -> None:
        """Start the thread (activate); ``stream`` is that of the frames to come."""
        self._slot = LatestSlot()
        self._thread = threading.Thread(target=self._run, args=(self._slot, stream),
                                        name='bbpose_worker', daemon=True)
        self._thread.start()

    def offer(self, frame: Frame, camera: CameraModel | CameraInfo) -> None:
        """
        Hand a pair to the thread; one still waiting is dropped (``superseded``).

        ``camera`` is the frame's CameraModel, or for a compressed frame its CameraInfo.
        """
        if self._slot.put((frame, camera)) is not None:
            self._stats.count('superseded')

    def stop(self) -> None:
        """Close the slot; wait at most WORKER_JOIN_TIMEOUT_S for the frame in hand."""
        self._slot.close()
        if self._thread is not None:
            self._thread.join(WORKER_JOIN_TIMEOUT_S)
        self._thread = None

    def _run(self, slot: LatestSlot, stream: int) -> None:
        """Estimate and publish the newest pair until the slot closes."""
        while (item := slot.take()) is not None:
            frame, camera = item
            pipeline = self._pipeline()     # a run-time rebuild may swap it
            try:
                extra_ms = {}
                if frame.image_rgb is None:            # compressed: decoded now it is taken
                    start = time.perf_counter()
                    if (decoded := self._decode(frame, camera)) is None:
                        continue                       # dropped: counted and logged
                    frame, camera = decoded
                    extra_ms['image_decode'] = (time.perf_counter() - start) * 1e3
                if frame.stream != stream and isinstance(pipeline.pipeline, PoseTracker):
                    pipeline.pipeline.reset()
                    self._logger.info('tracks reset: the image stamps went back')
                stream = frame.stream
                image_rgb = self._rectifier(frame.image_rgb, camera)
                if isinstance(pipeline.pipeline, PoseTracker):
                    result = pipeline.pipeline.estimate(
                        image_rgb, camera.intrinsics,
                        stamp_s=stamp_to_ns(frame.header.stamp) * 1e-9,
                        frame_index=frame.index)
                else:
                    result = pipeline.pipeline.estimate(image_rgb, camera.intrinsics)
                self._publishers.publish(frame.header, image_rgb, camera.intrinsics,
                                         result.poses, pipeline)
                start = time.perf_counter()
                if self._mapping.observe(frame.header, camera.intrinsics, result.poses,
                                         pipeline):     # mapped now, not waiting for TF
                    extra_ms['map'] = (time.perf_counter() - start) * 1e3
            except Exception as err:  # noqa: B902 - keep serving whatever one frame does
                if not self._context.ok():
                    return        # shutting down: the frame in hand is abandoned
                self._problems.drop('failed', type(err).__name__,
                                    f'estimation failed (stamp {stamp_text(frame.header)}): '
                                    f'{type(err).__name__}: {err}')
                continue
            self._stats.add_timings(dict(
                result.timings_ms, **extra_ms,
                node=(time.perf_counter() - frame.received_s) * 1e3))
            self._stats.count('answered')
