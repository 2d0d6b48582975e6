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
``window`` frames; values are named ``<stage>_ms_median`` and ``<stage>_ms_p95``. Each
stage's rate over the same frames is ``<stage>_per_s`` (frames with that stage per second of
the window): ``total_per_s`` the frames answered, ``tracking_per_s`` those tracked and, in
stream mode, ``stream_job_per_s`` the background jobs adopted, whose ``stream_job`` latency
is how long the full pipeline ran and ``stream_age`` how old their poses were when adopted.

Besides the counters, conditions that last (``InputWatch``: no image for a while, a
publisher whose QoS keeps its messages away) hold the level at WARN for as long as they do,
as diagnostic_updater's frequency status does.
"""

from collections import Counter, deque
from collections.abc import Callable, Iterable, Mapping, Sequence
import threading
import time

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from bbpose_ros.core.pipeline.latency import timing_summary

# Frames dropped, by reason (values frames_<reason>), and problems that dropped no frame,
# each logged as a warning (values warnings_<kind>).
DROPS = ('superseded', 'unpaired', 'bad_image', 'bad_camera_info', 'stamp_repeated', 'failed')
WARNINGS = ('stamp_backwards', 'stamp_future', 'frame_id_empty', 'frame_id_mismatch',
            'qos_incompatible', 'parameters_refused', 'map_no_transform', 'map_bad_transform',
            'map_failed')
COUNTERS = ('received', 'answered', 'mapped') + DROPS + WARNINGS
_SUFFIX = '_ms_'


class NodeStats:
    """Thread-safe frame counters and a sliding window of per-frame latencies (ms)."""

    def __init__(self, window: int = 1000) -> None:
        self._lock = threading.Lock()
        self._counts = Counter()
        self._timings = deque(maxlen=window)     # (time.monotonic() s, {stage: ms})
        self._reported = (0, 0)     # (drops, warnings) at the previous status

    def count(self, key: str) -> None:
        """Add one to a counter of COUNTERS."""
        with self._lock:
            self._counts[key] += 1

    def add_timings(self, timings_ms: Mapping[str, float], now_s: float | None = None) -> None:
        """Record one answered frame's {stage: ms}, answered at ``now_s`` (monotonic s)."""
        with self._lock:
            self._timings.append((time.monotonic() if now_s is None else now_s,
                                  dict(timings_ms)))

    def status(self, name: str, state: str = 'active', failure: str | None = None,
               conditions: Sequence[str] = ()) -> DiagnosticStatus:
        """
        Make a DiagnosticStatus of the counters, latencies and the node's lifecycle state.

        WARN when frames were dropped or warnings counted since the previous status, or
        while one of ``conditions`` (texts, ``InputWatch.conditions``) holds; ERROR with
        the reason when the last lifecycle transition failed (``failure``).
        ``lifecycle_state`` is one of unconfigured, inactive, active, finalized.
        """
        with self._lock:
            counts = {key: self._counts[key] for key in COUNTERS}
            summary = timing_summary([timings for _, timings in self._timings])
            rates = stage_rates(self._timings)
        problems = (sum(counts[key] for key in DROPS), sum(counts[key] for key in WARNINGS))
        level, message = DiagnosticStatus.OK, f'{counts["answered"]} frames answered'
        for now, before, what in zip(problems, self._reported, ('dropped', 'warnings')):
            if now > before:
                level = DiagnosticStatus.WARN
                message += f', {now - before} {what} since the last report'
        self._reported = problems
        for condition in conditions:
            level, message = DiagnosticStatus.WARN, f'{message}; {condition}'
        if state != 'active':
            message = f'{state}; {message}'
        if failure is not None:
            level, message = DiagnosticStatus.ERROR, f'{failure}; {message}'
        values = [KeyValue(key='lifecycle_state', value=state)]
        values += [KeyValue(key=f'{_prefix(key)}{key}', value=str(counts[key]))
                   for key in COUNTERS]
        values += [KeyValue(key=f'{stage}{_SUFFIX}{stat}', value=f'{ms:.3f}')
                   for stage, stats in summary.items() for stat, ms in stats.items()]
        values += [KeyValue(key=f'{stage}_per_s', value=f'{rate:.3f}')
                   for stage, rate in rates.items()]
        return DiagnosticStatus(level=level, name=name, message=message,
                                hardware_id='', values=values)


def stage_rates(frames: Sequence[tuple[float, Mapping[str, float]]]) -> dict[str, float]:
    """
    {stage: frames with it per second} over (time s, {stage: ms}) frames in time order.

    The rate is over the frames' time span: empty with fewer than two frames.
    """
    if len(frames) < 2 or frames[-1][0] <= frames[0][0]:
        return {}
    span_s = frames[-1][0] - frames[0][0]
    counts = Counter(stage for _, timings in frames for stage in timings)
    # n frames span n - 1 intervals.
    scale = (len(frames) - 1) / len(frames) / span_s
    return {stage: count * scale for stage, count in sorted(counts.items())}


class InputWatch:
    """
    Conditions of the node's input that last: no image for ``stale_s``, an incompatible QoS.

    ``start`` (activate) starts the clock; each image restarts it and ends an incompatible
    publisher's condition (images arrive again); ``stop`` (deactivate) ends both.

    Args:
        stale_s: seconds without an image, while serving, before it is a condition.
        clock: monotonic clock in seconds (replaceable in tests).

    """

    def __init__(self, stale_s: float, clock: Callable[[], float] = time.monotonic) -> None:
        self.stale_s = stale_s
        self._clock = clock
        self._last_s: float | None = None        # None: not serving
        self._incompatible: str | None = None

    def start(self) -> None:
        """Start watching: the node serves from now on."""
        self._last_s, self._incompatible = self._clock(), None

    def stop(self) -> None:
        """Stop watching: the node takes no input."""
        self._last_s = self._incompatible = None

    def image(self) -> None:
        """Note an image: input arrives."""
        if self._last_s is not None:
            self._last_s, self._incompatible = self._clock(), None

    def incompatible(self, text: str) -> None:
        """Note an incompatible publisher; ``text`` says which and why."""
        if self._last_s is not None:
            self._incompatible = text

    def conditions(self, topic: str) -> list[str]:
        """Return the conditions holding now, as texts naming the image ``topic``."""
        if self._last_s is None:
            return []
        held = [] if self._incompatible is None else [self._incompatible]
        quiet_s = self._clock() - self._last_s
        if quiet_s > self.stale_s:
            held.append(f'no image on {topic} for {quiet_s:.0f} s')
        return held


def incompatible_qos_text(topic: str, policy: str, reliability: str) -> str:
    """
    Say that a publisher on ``topic`` offers QoS incompatible in ``policy``, and what to do.

    Only the policy that differs is named: the node's ``qos_reliability`` (now
    ``reliability``) for the reliability policy, the publisher's QoS for any other (this
    node's subscriptions are volatile, with no deadline and automatic liveliness).
    """
    fix = (f'set parameter qos_reliability (now {reliability}) to match it, or the '
           "publisher's reliability" if policy == 'reliability'
           else f"change the publisher's {policy}")
    return (f'a publisher on {topic} offers QoS incompatible with this subscription '
            f'({policy} policy): nothing it sends arrives; {fix}')


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
