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

"""Videos: written atomically, decoded back frame by frame; bad input leaves no file."""

import cv2
import numpy as np
import pytest

from bbpose_ros.core.eval.video import write_video
from bbpose_ros.core.util.errors import InputError


def decode(path):
    """Every frame of a video, RGB, as OpenCV decodes it."""
    capture, frames = cv2.VideoCapture(str(path)), []
    while (read := capture.read())[0]:
        frames.append(cv2.cvtColor(read[1], cv2.COLOR_BGR2RGB))
    capture.release()
    return frames


def test_written_frames_decode_back(tmp_path):
    frames = [np.full((48, 64, 3), (40 * k, 100, 250 - 40 * k), np.uint8) for k in range(5)]
    assert write_video(tmp_path / 'out.mp4', frames, fps=5.0) == 5
    decoded = decode(tmp_path / 'out.mp4')
    assert len(decoded) == 5
    for mine, theirs in zip(decoded, frames):
        assert mine.shape == theirs.shape
        assert np.abs(mine.astype(int) - theirs).mean() < 8    # lossy, but these colours
    assert [p.name for p in tmp_path.iterdir()] == ['out.mp4']


def test_bad_frames_leave_no_file(tmp_path):
    with pytest.raises(InputError, match='frame 1 is 32x48, the first was 64x48'):
        write_video(tmp_path / 'out.mp4', [np.zeros((48, 64, 3), np.uint8),
                                           np.zeros((48, 32, 3), np.uint8)], fps=5.0)
    with pytest.raises(InputError, match='no frames'):
        write_video(tmp_path / 'out.mp4', [], fps=5.0)
    with pytest.raises(InputError, match='ending in .mp4'):
        write_video(tmp_path / 'out.avi', [np.zeros((48, 64, 3), np.uint8)], fps=5.0)
    assert list(tmp_path.iterdir()) == []
