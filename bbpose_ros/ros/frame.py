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

"""A camera frame as the node's intake hands it to the worker."""

from dataclasses import dataclass

import numpy as np
from sensor_msgs.msg import CompressedImage
from std_msgs.msg import Header


@dataclass(frozen=True)
class Frame:
    """
    An image: its header, (H, W, 3) uint8 RGB pixels, perf_counter at receipt.

    ``stream`` counts the backward stamp jumps before it: frames of one stream follow
    each other in time, so a tracker resets when the stream changes. ``index`` counts the
    images of its stream received before it, those dropped later included: with the stamps
    it gives the camera's frame period (``PoseTracker``). A compressed image
    waits undecoded: ``image_rgb`` None and ``compressed`` its message, until
    ``FrameIntake.decode``.
    """

    header: Header
    image_rgb: np.ndarray | None
    received_s: float
    stream: int
    index: int
    compressed: CompressedImage | None = None


def stamp_text(header: Header) -> str:
    """Return a header's stamp as 'seconds.nanoseconds' for log lines."""
    return f'{header.stamp.sec}.{header.stamp.nanosec:09d}'
