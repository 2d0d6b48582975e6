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
Image / CameraInfo pairing by header stamp.

Plain Python (no rclpy): stamps are integer nanoseconds, payloads are opaque. A short queue
of images waits for their CameraInfo (as message_filters' ApproximateTime keeps one per
topic), so a CameraInfo that arrives after the next image still pairs its own; only the
newest pair waits for the worker (``core/util/latest_slot.py``), so a slow pipeline never
builds a backlog.
"""

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
import time
from typing import Any

# Why a waiting image was dropped (``Pairing.dropped``).
NEWER_PAIRED = 'a newer image was paired first'
QUEUE_FULL = 'the images waiting for a camera_info fill the queue'


@dataclass
class Pairing:
    """
    What offering an image or a CameraInfo did.

    Attributes:
        pairs: the (image, info) pairs it completed, oldest first.
        dropped: the (image, reason) of waiting images it gave up, oldest first.

    """

    pairs: list[tuple[Any, Any]] = field(default_factory=list)
    dropped: list[tuple[Any, str]] = field(default_factory=list)


class StampPairer:
    """
    Pairs each image with the CameraInfo nearest in stamp, within a slop.

    Images without a CameraInfo yet wait in arrival order. Frames never go out of order:
    when an image pairs, the older images still waiting are dropped (``NEWER_PAIRED``).

    Args:
        info_history: how many recent CameraInfos are kept to pair late images with.
        max_waiting: how many images may wait for their CameraInfo; a further one drops
            the oldest (``QUEUE_FULL``).
        clock: monotonic clock in seconds (replaceable in tests), for ``expire``.

    """

    def __init__(self, info_history: int = 50, max_waiting: int = 8,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._infos = deque(maxlen=info_history)
        self._waiting = deque()          # (stamp_ns, image, arrival_s), oldest first
        self._max_waiting = max_waiting
        self._clock = clock

    def add_image(self, stamp_ns: int, image: Any, slop_s: float) -> Pairing:
        """
        Offer an image: paired at once when its CameraInfo is here, else queued.

        ``slop_s`` < 0 pairs with the latest CameraInfo whatever its stamp.
        """
        info = self._match(stamp_ns, slop_s)
        if info is not None:
            return Pairing(pairs=[(image, info)], dropped=self._drop_waiting(len(self._waiting),
                                                                             NEWER_PAIRED))
        self._waiting.append((stamp_ns, image, self._clock()))
        excess = len(self._waiting) - self._max_waiting
        return Pairing(dropped=self._drop_waiting(max(0, excess), QUEUE_FULL))

    def add_info(self, stamp_ns: int, info: Any, slop_s: float) -> Pairing:
        """Store a CameraInfo; pair the waiting images it completes (older ones dropped)."""
        self._infos.append((stamp_ns, info))
        matches = [self._match(stamp, slop_s) for stamp, _, _ in self._waiting]
        newest = max((k for k, match in enumerate(matches) if match is not None), default=-1)
        pairing = Pairing()
        for k in range(newest + 1):
            _, image, _ = self._waiting.popleft()
            if matches[k] is not None:
                pairing.pairs.append((image, matches[k]))
            else:
                pairing.dropped.append((image, NEWER_PAIRED))
        return pairing

    def expire(self, timeout_s: float) -> list[Any]:
        """Remove and return the images that waited longer than ``timeout_s``, oldest first."""
        now = self._clock()
        expired = []
        while self._waiting and now - self._waiting[0][2] > timeout_s:
            expired.append(self._waiting.popleft()[1])
        return expired

    @property
    def waiting(self) -> list[Any]:
        """Return the images waiting for a CameraInfo, oldest first."""
        return [image for _, image, _ in self._waiting]

    def nearest_offset_s(self, stamp_ns: int) -> float | None:
        """Return |stamp - nearest CameraInfo stamp| in seconds, or None with no CameraInfo."""
        if not self._infos:
            return None
        return min(abs(stamp - stamp_ns) for stamp, _ in self._infos) * 1e-9

    def _drop_waiting(self, count: int, reason: str) -> list[tuple[Any, str]]:
        return [(self._waiting.popleft()[1], reason) for _ in range(count)]

    def _match(self, stamp_ns: int, slop_s: float) -> Any | None:
        if not self._infos:
            return None
        if slop_s < 0:
            return self._infos[-1][1]
        stamp, info = min(self._infos, key=lambda item: abs(item[0] - stamp_ns))
        return info if abs(stamp - stamp_ns) <= slop_s * 1e9 else None
