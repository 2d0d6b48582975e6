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
A one-item hand-off between threads in which the newest item wins (``LatestSlot``).

A producer puts items faster than a consumer takes them; an item put while one waits
replaces it (``put`` returns the one replaced, never taken), so the consumer always takes
the newest and no backlog builds. The node's worker takes its frames through one, and so
does stream mode's full pipeline beside the tracks (``pipeline.background_detection``).
"""

import threading
from typing import Any


class LatestSlot:
    """
    A one-item hand-off between threads: put replaces, take waits.

    Args:
        condition: the condition the slot locks and waits on; pass the owner's (made with an
            ``RLock``) to read the slot and the owner's own state under one lock, and to
            ``take`` while holding it. None: a condition of its own.

    """

    def __init__(self, condition: threading.Condition | None = None) -> None:
        self._item = None
        self._closed = False
        self._condition = condition if condition is not None else threading.Condition()

    def put(self, item: Any) -> Any | None:
        """Offer an item; returns the item it replaced (never processed) or None."""
        with self._condition:
            replaced, self._item = self._item, item
            self._condition.notify_all()
        return replaced

    def take(self) -> Any | None:
        """Wait for an item and remove it; None once the slot is closed."""
        with self._condition:
            self._condition.wait_for(lambda: self._item is not None or self._closed)
            item, self._item = self._item, None
        return None if self._closed else item

    def close(self) -> None:
        """Wake the taker for good (shutdown): ``take`` returns None from now on."""
        with self._condition:
            self._closed = True
            self._condition.notify_all()

    def drop(self) -> Any | None:
        """Remove the item waiting without taking it; returns it, or None."""
        with self._condition:
            item, self._item = self._item, None
        return item

    @property
    def waiting(self) -> bool:
        """Tell whether an item waits to be taken (never once the slot is closed)."""
        with self._condition:
            return self._item is not None and not self._closed

    @property
    def closed(self) -> bool:
        """Tell whether the slot was closed."""
        with self._condition:
            return self._closed
