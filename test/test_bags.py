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
BOP frames -> rosbag2 -> frames again: images bit-exact, intrinsics and poses equal.

Recorded raw messages (``write_bag``) come back byte for byte, in any type the installed
packages define.
"""

import shutil

import numpy as np
import pytest
from rosbags.rosbag2 import Reader

from bbpose_ros.bags import topics
from bbpose_ros.bags.reader import read_bag_frames
from bbpose_ros.bags.typestore import TYPESTORE
from bbpose_ros.bags.writer import write_bag, write_bop_bag
from bbpose_ros.core.data.bop import BopDataset
from bbpose_ros.core.geometry.rotations import rotation_error_deg
from bbpose_ros.core.util.errors import InputError


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_round_trip(lmo_frames, tmp_path, storage):
    frames = lmo_frames[:4]
    bag = tmp_path / 'lmo_bag'
    write_bop_bag(frames, bag, rate_hz=5.0, start_stamp_ns=1_700_000_000_000_000_000,
                  frame_id='cam_optical', storage=storage, progress=False)
    read = read_bag_frames(bag)
    assert len(read) == len(frames)
    assert [f.stamp_ns for f in read] == [1_700_000_000_000_000_000 + i * 200_000_000
                                          for i in range(4)]
    for original, copy in zip(frames, read):
        assert copy.frame_id == 'cam_optical'
        assert np.array_equal(copy.image_rgb, original.load_image())
        np.testing.assert_allclose(copy.camera.k, original.camera.k)
        expected = [i for i in original.instances if i.visib_fract >= 0.1]
        assert sum(len(v) for v in copy.ground_truth.values()) == len(expected)
        for instance in expected:
            (rotation, translation), = copy.ground_truth[instance.object_name]
            # BOP's matrices are orthonormal to ~1e-4 only; the quaternion is the nearest.
            assert rotation_error_deg(rotation, instance.rotation) < 0.02
            np.testing.assert_allclose(translation, instance.translation, atol=1e-9)
    assert sorted(p.name for p in tmp_path.iterdir()) == ['lmo_bag']
    suffix = {'mcap': '.mcap', 'sqlite3': '.db3'}[storage]
    assert sorted(p.name for p in bag.iterdir()) == sorted(['metadata.yaml', 'lmo_bag' + suffix])


def test_failure_leaves_no_partial_bag(lmo_root, tmp_path):
    root = tmp_path / 'lmo'
    shutil.copytree(lmo_root / 'test', root / 'test')
    shutil.copy(lmo_root / 'camera.json', root)
    (root / 'test/000002/rgb/000017.png').write_bytes(b'not a png')
    frames = BopDataset(root).frames()[:5]
    with pytest.raises(InputError, match='000017.png'):
        write_bop_bag(frames, tmp_path / 'bag', progress=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ['lmo']


def test_refuses_to_overwrite(lmo_frames, tmp_path):
    (tmp_path / 'bag').mkdir()
    with pytest.raises(InputError, match='already exists'):
        write_bop_bag(lmo_frames[:1], tmp_path / 'bag', progress=False)


def test_raw_messages_come_back_and_replace_only_a_bag(tmp_path):
    pose = topics.pose_message(5, 'cam', np.eye(3), [0.0, 0.0, 1.0])
    raw = TYPESTORE.serialize_cdr(pose, topics.POSE_TYPE).tobytes()
    detections = 'vision_msgs/msg/Detection3DArray'     # a type rosbags lacks
    messages = [('/a/pose', topics.POSE_TYPE, 10, raw), ('/a/pose', topics.POSE_TYPE, 20, raw),
                ('/detections', detections, 30, b'opaque: written as given')]
    bag = tmp_path / 'results'
    assert write_bag(bag, messages[:1]) == 1
    with pytest.raises(InputError, match='already exists'):
        write_bag(bag, messages)
    assert write_bag(bag, messages, replace=True) == 3
    with Reader(bag) as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == {
            '/a/pose': topics.POSE_TYPE, '/detections': detections}
        assert [(c.topic, t, bytes(r)) for c, t, r in reader.messages()] == [
            (topic, time_ns, data) for topic, _, time_ns, data in messages]
    (tmp_path / 'notes').mkdir()
    with pytest.raises(InputError, match='is not a bag; not replacing it'):
        write_bag(tmp_path / 'notes', messages, replace=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ['notes', 'results']
