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

"""The newest-item-wins hand-off between threads (core/util/latest_slot.py)."""

import threading

from bbpose_ros.core.util.latest_slot import LatestSlot


def test_latest_slot_keeps_only_the_newest_item():
    slot = LatestSlot()
    assert slot.put(1) is None
    assert slot.put(2) == 1
    assert slot.waiting
    assert slot.take() == 2
    assert not slot.waiting
    taken = []
    worker = threading.Thread(target=lambda: taken.append(slot.take()))
    worker.start()
    slot.close()
    worker.join(5.0)
    assert taken == [None]
    assert slot.closed


def test_a_closed_slot_has_nothing_waiting():
    slot = LatestSlot()
    slot.put(1)
    slot.close()
    assert not slot.waiting
    assert slot.drop() == 1 and slot.drop() is None
    assert slot.take() is None


def test_a_slot_on_its_owners_condition_is_taken_under_the_owners_lock():
    condition = threading.Condition(threading.RLock())
    slot = LatestSlot(condition)
    taken = []

    def take():
        with condition:         # the owner's state and the slot change together
            taken.append(slot.take())

    worker = threading.Thread(target=take)
    worker.start()
    slot.put('frame')
    worker.join(5.0)
    assert taken == ['frame'] and not slot.waiting
