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
Frame counters and stage latencies of the node, as a diagnostic_msgs/DiagnosticArray.

Latencies are milliseconds: the pipeline's stages (detector, rotation, translation, total)
and ``node`` (image received -> results published), each as median and p95 over the last
``window`` frames; values are named ``<stage>_ms_median`` and ``<stage>_ms_p95``.
"""

from collections import Counter, deque
from collections.abc import Iterable, Mapping
import threading

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from bbpose_ros.core.latency import timing_summary

# Frames dropped, by reason (values frames_<reason>), and problems that dropped no frame,
# each logged as a warning (values warnings_<kind>).
DROPS = ('superseded', 'unpaired', 'bad_image', 'bad_camera_info', 'stamp_repeated', 'failed')
WARNINGS = ('stamp_backwards', 'stamp_future', 'frame_id_empty', 'qos_incompatible',
            'parameters_refused')
COUNTERS = ('received', 'answered') + DROPS + WARNINGS
_SUFFIX = '_ms_'


class NodeStats:
    """Thread-safe frame counters and a sliding window of per-frame latencies (ms)."""

    def __init__(self, window: int = 1000) -> None:
        self._lock = threading.Lock()
        self._counts = Counter()
        self._timings = deque(maxlen=window)
        self._reported = (0, 0)     # (drops, warnings) at the previous status

    def count(self, key: str) -> None:
        """Add one to a counter of COUNTERS."""
        with self._lock:
            self._counts[key] += 1

    def add_timings(self, timings_ms: Mapping[str, float]) -> None:
        """Record one answered frame's {stage: ms}."""
        with self._lock:
            self._timings.append(dict(timings_ms))

    def status(self, name: str, state: str = 'active',
               failure: str | None = None) -> DiagnosticStatus:
        """
        Make a DiagnosticStatus of the counters, latencies and the node's lifecycle state.

        WARN when frames were dropped or warnings counted since the previous status; ERROR
        with the reason when the last lifecycle transition failed (``failure``).
        ``lifecycle_state`` is one of unconfigured, inactive, active.
        """
        with self._lock:
            counts = {key: self._counts[key] for key in COUNTERS}
            summary = timing_summary(list(self._timings))
        problems = (sum(counts[key] for key in DROPS), sum(counts[key] for key in WARNINGS))
        level, message = DiagnosticStatus.OK, f'{counts["answered"]} frames answered'
        for now, before, what in zip(problems, self._reported, ('dropped', 'warnings')):
            if now > before:
                level = DiagnosticStatus.WARN
                message += f', {now - before} {what} since the last report'
        self._reported = problems
        if state != 'active':
            message = f'{state}; {message}'
        if failure is not None:
            level, message = DiagnosticStatus.ERROR, f'{failure}; {message}'
        values = [KeyValue(key='lifecycle_state', value=state)]
        values += [KeyValue(key=f'{_prefix(key)}{key}', value=str(counts[key]))
                   for key in COUNTERS]
        values += [KeyValue(key=f'{stage}{_SUFFIX}{stat}', value=f'{ms:.3f}')
                   for stage, stats in summary.items() for stat, ms in stats.items()]
        return DiagnosticStatus(level=level, name=name, message=message,
                                hardware_id='', values=values)


def diagnostics_message(stamp: Time, statuses: Iterable[DiagnosticStatus]) -> DiagnosticArray:
    """Make a DiagnosticArray of the statuses at a builtin_interfaces/Time."""
    message = DiagnosticArray(status=list(statuses))
    message.header.stamp = stamp
    return message


def timings_from_status(status: DiagnosticStatus) -> dict[str, dict[str, float]]:
    """{stage: {'median', 'p95'}} ms read back from a status made by NodeStats.status."""
    timings = {}
    for item in status.values:
        stage, found, stat = item.key.rpartition(_SUFFIX)
        if found:
            timings.setdefault(stage, {})[stat] = float(item.value)
    return timings


def counts_from_status(status: DiagnosticStatus) -> dict[str, int]:
    """{counter: int} of every counter of COUNTERS, read back from a NodeStats status."""
    values = {item.key: item.value for item in status.values}
    return {key: int(values[f'{_prefix(key)}{key}']) for key in COUNTERS
            if f'{_prefix(key)}{key}' in values}


def _prefix(counter):
    return 'warnings_' if counter in WARNINGS else 'frames_'
