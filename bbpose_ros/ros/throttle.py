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
Log throttling per kind of problem.

rclpy's ``throttle_duration_sec`` throttles per call site, so a second, different bad input
arriving soon after a first one would go unreported. Here each key (e.g. the field that
was wrong) has its own period: a repeated problem is logged once per period, a new one at
once. ``ProblemLog`` counts every problem (for /diagnostics) and logs it so throttled.
"""

from collections.abc import Callable, Hashable
import threading
import time

from rclpy.impl.rcutils_logger import RcutilsLogger


class KeyedThrottle:
    """
    Decides whether a message of a given key may be logged now.

    Keys are forgotten once their period is over and more than ``max_keys`` are held, so
    a stream of ever-different problems (keys often hold the bad value) cannot grow it
    without bound.

    Args:
        period_s: least time between two messages of the same key, seconds.
        clock: monotonic clock in seconds (replaceable in tests).
        max_keys: how many keys are held before expired ones are forgotten.

    """

    def __init__(self, period_s: float = 5.0,
                 clock: Callable[[], float] = time.monotonic, max_keys: int = 256) -> None:
        self.period_s = period_s
        self.max_keys = max_keys
        self._clock = clock
        self._last = {}
        self._lock = threading.Lock()

    def allow(self, key: Hashable) -> bool:
        """Return True (and record it) when no ``key`` message was allowed within the period."""
        now = self._clock()
        with self._lock:
            if now - self._last.get(key, -float('inf')) < self.period_s:
                return False
            if len(self._last) >= self.max_keys:
                self._last = {k: t for k, t in self._last.items() if now - t < self.period_s}
            self._last[key] = now
            return True

    def __len__(self) -> int:
        """Return how many keys are held."""
        return len(self._last)


class ProblemLog:
    """
    Counts each problem and logs it, throttled per (counter, key).

    Args:
        count: adds one to a counter (``NodeStats.count``).
        logger: the node's logger.
        throttle: decides what is logged now; a KeyedThrottle of its default period if None.

    """

    def __init__(self, count: Callable[[str], None], logger: RcutilsLogger,
                 throttle: KeyedThrottle | None = None) -> None:
        self._count = count
        self._logger = logger
        self._throttle = KeyedThrottle() if throttle is None else throttle

    def warn(self, counter: str, key: str, text: str) -> None:
        """Count ``counter``; log ``text`` as a warning, throttled per (counter, key)."""
        self._count(counter)
        if self._throttle.allow(f'{counter}:{key}'):
            self._logger.warning(text)

    def drop(self, counter: str, key: str, text: str) -> None:
        """Count a frame dropped for bad input; log ``text`` as an error, throttled."""
        self._count(counter)
        if self._throttle.allow(f'{counter}:{key}'):
            self._logger.error(text)
