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
Image / CameraInfo pairing by header stamp and the one-frame hand-off to the worker.

Plain Python (no rclpy): stamps are integer nanoseconds, payloads are opaque. Only the
newest image waits for its CameraInfo and only the newest pair waits for the worker, so a
slow pipeline never builds a backlog.
"""

from collections import deque
import threading
from typing import Any


class StampPairer:
    """
    Pairs each image with the CameraInfo nearest in stamp, within a slop.

    Args:
        info_history: how many recent CameraInfos are kept to pair late images with.

    """

    def __init__(self, info_history: int = 50) -> None:
        self._infos = deque(maxlen=info_history)
        self._waiting = None

    def add_image(self, stamp_ns: int, image: Any,
                  slop_s: float) -> tuple[tuple[Any, Any] | None, Any | None]:
        """
        Offer an image; returns (pair or None, the image it displaced or None).

        A pair is (image, info). An image without a CameraInfo yet waits; either way an
        older waiting image is displaced, so frames never go out of order. ``slop_s`` < 0
        pairs with the latest CameraInfo whatever its stamp.
        """
        info = self._match(stamp_ns, slop_s)
        displaced = self.take_waiting()
        if info is not None:
            return (image, info), displaced
        self._waiting = (stamp_ns, image)
        return None, displaced

    def add_info(self, stamp_ns: int, info: Any, slop_s: float) -> tuple[Any, Any] | None:
        """Store a CameraInfo; returns the (image, info) pair it completes, or None."""
        self._infos.append((stamp_ns, info))
        if self._waiting is None:
            return None
        match = self._match(self._waiting[0], slop_s)
        if match is None:
            return None
        image, self._waiting = self._waiting[1], None
        return image, match

    @property
    def waiting(self) -> Any | None:
        """Return the image waiting for a CameraInfo, or None."""
        return None if self._waiting is None else self._waiting[1]

    def take_waiting(self) -> Any | None:
        """Remove and return the image waiting for a CameraInfo (None when there is none)."""
        waiting, self._waiting = self.waiting, None
        return waiting

    def nearest_offset_s(self, stamp_ns: int) -> float | None:
        """Return |stamp - nearest CameraInfo stamp| in seconds, or None with no CameraInfo."""
        if not self._infos:
            return None
        return min(abs(stamp - stamp_ns) for stamp, _ in self._infos) * 1e-9

    def _match(self, stamp_ns, slop_s):
        if not self._infos:
            return None
        if slop_s < 0:
            return self._infos[-1][1]
        stamp, info = min(self._infos, key=lambda item: abs(item[0] - stamp_ns))
        return info if abs(stamp - stamp_ns) <= slop_s * 1e9 else None


class LatestSlot:
    """A one-item hand-off between threads: put replaces, take waits."""

    def __init__(self) -> None:
        self._item = None
        self._closed = False
        self._condition = threading.Condition()

    def put(self, item: Any) -> Any | None:
        """Offer an item; returns the item it replaced (never processed) or None."""
        with self._condition:
            replaced, self._item = self._item, item
            self._condition.notify()
        return replaced

    def take(self) -> Any | None:
        """Wait for an item and remove it; None once the slot is closed."""
        with self._condition:
            self._condition.wait_for(lambda: self._item is not None or self._closed)
            item, self._item = self._item, None
        return None if self._closed else item

    def close(self) -> None:
        """Wake the taker for good (shutdown)."""
        with self._condition:
            self._closed = True
            self._condition.notify_all()
