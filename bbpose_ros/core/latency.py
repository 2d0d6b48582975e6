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
``timing_summary`` is the compact form of the reports and of /diagnostics.
"""

from typing import Iterable, Mapping

import numpy as np


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
