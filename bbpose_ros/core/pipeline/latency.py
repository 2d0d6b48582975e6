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
Latency statistics of per-frame stage timings, in milliseconds.

One computation serves the node's diagnostics, the evaluation report and the benchmarks;
``timing_summary`` is the compact form of the reports and of /diagnostics. ``StageTimer``
measures the stages of one frame, for the pipeline, the tracker and the evaluation alike.
"""

import time
from typing import Iterable, Mapping

import numpy as np


class StageTimer:
    """
    Wall-clock milliseconds of the stages of one frame, ``perf_counter`` based.

    ``lap(stage)`` records the time since the previous lap (or the timer's start) under
    ``stage``; ``total()`` adds 'total', the time since the start, and returns
    ``timings_ms`` ({stage: ms}, in the order the stages ran).
    """

    def __init__(self) -> None:
        self.timings_ms: dict[str, float] = {}
        self._start = self._last = time.perf_counter()

    @property
    def start_s(self) -> float:
        """Return the ``perf_counter`` seconds the timer started at."""
        return self._start

    def lap(self, stage: str | None) -> None:
        """Record the time since the last lap under ``stage`` (None: skip it unrecorded)."""
        now = time.perf_counter()
        if stage is not None:
            self.timings_ms[stage] = (now - self._last) * 1e3
        self._last = now

    def total(self) -> dict[str, float]:
        """Record and return the timings with 'total', the time since the start."""
        self.timings_ms['total'] = (time.perf_counter() - self._start) * 1e3
        return self.timings_ms


def latency_stats(values_ms: Iterable[float]) -> dict:
    """Return {'median_ms', 'p95_ms', 'max_ms'} of durations in ms (None when there are none)."""
    values = np.asarray(list(values_ms), dtype=float)
    if not values.size:
        return {'median_ms': None, 'p95_ms': None, 'max_ms': None}
    return {'median_ms': float(np.median(values)), 'p95_ms': float(np.percentile(values, 95)),
            'max_ms': float(values.max())}


def stage_stats(per_frame: Iterable[Mapping[str, float]]) -> dict:
    """Return {stage: latency_stats} over per-frame {stage: ms} dicts, in order of appearance."""
    per_frame = list(per_frame)
    stages = list(dict.fromkeys(stage for frame in per_frame for stage in frame))
    return {stage: latency_stats([frame[stage] for frame in per_frame if stage in frame])
            for stage in stages}


def timing_summary(per_frame: Iterable[Mapping[str, float]]) -> dict:
    """Return {stage: {'median', 'p95'}} in ms over per-frame {stage: ms} dicts, stages sorted."""
    stats = stage_stats(per_frame)
    return {stage: {'median': stats[stage]['median_ms'], 'p95': stats[stage]['p95_ms']}
            for stage in sorted(stats)}
