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
The full pipeline beside the tracks: one job at a time, on the newest frame handed to it.

Stream mode (``tracking_stream``) answers every frame from the tracks and hands frames to a
``BackgroundDetection``, which runs the PosePipeline (detector, Q-Net, Bounding Box
Equation, refinement) in a thread of its own. Frames are never queued: a frame handed while
a job runs waits in a one-frame slot (``LatestSlot``), and a newer one replaces it; when the
job ends, the next takes the frame waiting. The finished job's poses wait until the
tracker ``take``s them (the newest only).

The pipeline's detector and Q-Net (ONNX Runtime) and the refinement's numba kernels
(``nogil``) release the GIL, so the job runs on the cores the tracks leave. Only this
thread calls the PosePipeline while a job runs or a frame waits (``idle`` tells when it
does not); the tracker calls its PoseRefiner's ``refine_tracks``, which
keeps no state between calls (``refine_poses`` builds its own per call), and the parallel
kernels are safe to launch from both threads (``kernel_launch.parallel_launch``).
"""

from __future__ import annotations

from dataclasses import dataclass
import threading
import time

import numpy as np

from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.pipeline.pose_pipeline import PosePipeline
from bbpose_ros.core.pipeline.poses import FrameResult
from bbpose_ros.core.util.latest_slot import LatestSlot

# A stop waits this long for the job in hand (one run of the full pipeline) to end.
STOP_TIMEOUT_S = 30.0


@dataclass(frozen=True)
class FinishedJob:
    """
    One run of the full pipeline, finished.

    Attributes:
        result: its FrameResult (poses as of the frame it ran on), or None when it failed.
        error: the exception it raised, or None.
        handed_s: ``time.perf_counter()`` seconds when its frame was handed over.
        started_s: when the job took the frame.
        finished_s: when it ended.

    """

    result: FrameResult | None
    error: BaseException | None
    handed_s: float
    started_s: float
    finished_s: float

    @property
    def run_ms(self) -> float:
        """Return how long the full pipeline ran, milliseconds."""
        return (self.finished_s - self.started_s) * 1e3


class BackgroundDetection:
    """
    Runs a PosePipeline on the newest handed frame in a thread of its own, one job at a time.

    The thread starts with the first frame handed and ends with ``stop``; a stopped one
    starts again with the next frame, unless it was stopped for good (``close``).

    Args:
        pipeline: the PosePipeline; only this thread calls it while it runs.

    """

    def __init__(self, pipeline: PosePipeline) -> None:
        self._pipeline = pipeline
        # One lock for the slot and the state below: a frame taken is a job running.
        self._changed = threading.Condition(threading.RLock())
        # The current thread's frames, (image, camera, handed_s); closed when it stops.
        self._slot: LatestSlot | None = None
        self._finished: FinishedJob | None = None
        self._thread: threading.Thread | None = None
        self._closed = False
        self._busy = False      # a job runs

    @property
    def waiting(self) -> bool:
        """Tell whether a handed frame waits for the job in hand to end."""
        with self._changed:
            return self._slot is not None and self._slot.waiting

    @property
    def idle(self) -> bool:
        """Tell whether the pipeline is free to call: no job runs or waits, not closed."""
        with self._changed:
            return not self._busy and not self.waiting and not self._closed

    @property
    def running(self) -> bool:
        """Tell whether the thread is alive (a job running or waiting for a frame)."""
        thread = self._thread
        return thread is not None and thread.is_alive()

    def hand(self, image_rgb: np.ndarray, camera: CameraIntrinsics) -> None:
        """
        Hand over the newest frame; one still waiting is replaced (never queued).

        The job reads ``image_rgb`` later: the caller must not write to it afterwards.
        A closed BackgroundDetection ignores it.
        """
        with self._changed:
            if self._closed:
                return
            if self._thread is None:
                self._slot = LatestSlot(self._changed)
                self._thread = threading.Thread(target=self._run, args=(self._slot,),
                                                name='bbpose_detection', daemon=True)
                self._thread.start()
            self._slot.put((image_rgb, camera, time.perf_counter()))

    def take(self) -> FinishedJob | None:
        """Return the newest finished job not taken yet (an older one is dropped), or None."""
        with self._changed:
            finished, self._finished = self._finished, None
        return finished

    def stop(self) -> None:
        """End the thread after the job in hand (its poses are dropped); forget the frames."""
        with self._changed:
            thread, self._thread = self._thread, None
            if self._slot is not None:      # the thread woken, the frame waiting dropped
                self._slot.close()
                self._slot.drop()
        if thread is not None and thread is not threading.current_thread():
            thread.join(STOP_TIMEOUT_S)
        with self._changed:
            self._finished = None

    def close(self) -> None:
        """Stop for good: frames handed later are ignored."""
        with self._changed:
            self._closed = True
        self.stop()

    def _run(self, slot: LatestSlot) -> None:
        """Thread: run the pipeline on each frame handed, until ``slot`` is closed."""
        while True:
            with self._changed:
                if (frame := slot.take()) is None:
                    return
                image_rgb, camera, handed_s = frame
                self._busy = True
            started_s = time.perf_counter()
            result = error = None
            try:
                result = self._pipeline.estimate(image_rgb, camera)
            except Exception as err:  # noqa: B902 - handed to the tracker, which raises it
                error = err
            with self._changed:
                if slot is self._slot:      # a thread stopped and replaced leaves it
                    self._busy = False
                if slot.closed:
                    return
                self._finished = FinishedJob(result, error, handed_s, started_s,
                                             time.perf_counter())
