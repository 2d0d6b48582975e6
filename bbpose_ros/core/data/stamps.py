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
Header stamps: their nanoseconds, and what is odd about an image's stamp in a stream.

Plain Python (no rclpy): ``stamp_to_ns`` reads any builtin_interfaces/Time (rclpy's or
rosbags'), and ``StampChecker`` works on integer nanoseconds. A stamp equal to the previous one
repeats a frame already handled (the node drops it, so each stamp is answered once); an
older one means the source went back (a reordering publisher, a restarted camera or bag);
one ahead of the clock by more than a tolerance means the source's clock is not this
machine's. The node answers the last two and says so.
"""

from typing import Any

REPEATED = 'stamp_repeated'
BACKWARDS = 'stamp_backwards'
FUTURE = 'stamp_future'


def stamp_to_ns(stamp: Any) -> int:
    """Nanoseconds of a builtin_interfaces/Time (anything with ``sec`` and ``nanosec``)."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


class StampChecker:
    """
    Tells repeated, backward and future image stamps; remembers the latest one seen.

    Args:
        future_tolerance_ns: how far ahead of the clock a stamp may be.

    """

    def __init__(self, future_tolerance_ns: int) -> None:
        self.future_tolerance_ns = future_tolerance_ns
        self._previous = None

    def check(self, stamp_ns: int, now_ns: int) -> tuple[str, str] | None:
        """
        Check an image's stamp and remember it; returns (kind, description) or None.

        ``kind`` is REPEATED, BACKWARDS or FUTURE (in that order of precedence); the
        description names the field and the figures.
        """
        previous, self._previous = self._previous, stamp_ns
        if previous is not None and stamp_ns == previous:
            return REPEATED, "header.stamp repeats the previous image's"
        if previous is not None and stamp_ns < previous:
            return BACKWARDS, (f'header.stamp is {(previous - stamp_ns) * 1e-9:.3f} s older '
                               f"than the previous image's")
        if stamp_ns - now_ns > self.future_tolerance_ns:
            return FUTURE, (f'header.stamp is {(stamp_ns - now_ns) * 1e-9:.3f} s ahead of '
                            f"this node's clock")
        return None
