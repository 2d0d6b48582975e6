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

"""``bbpose play``: a bag's messages reach subscribers unchanged, with recorded stamps."""

import subprocess
import sys

from geometry_msgs.msg import PoseStamped
import numpy as np
import pytest
from sensor_msgs.msg import CameraInfo, Image
from test_ros_support import GraphClient, use_private_domain

from bbpose_ros.bags import topics
from bbpose_ros.bags.player import BagPlayer
from bbpose_ros.bags.reader import read_bag_frames
from bbpose_ros.bags.writer import write_bop_bag
from bbpose_ros.core.data.stamps import stamp_to_ns
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.ros.conversions import image_to_rgb

pytestmark = pytest.mark.slow   # runs bbpose play as a process

FRAMES = 3


def test_play_publishes_the_bag_with_its_stamps(lmo, tmp_path):
    use_private_domain(offset=2)
    bag = tmp_path / 'bag'
    write_bop_bag(lmo.frames()[:FRAMES], bag, rate_hz=20.0, start_stamp_ns=5 * 10 ** 9,
                  progress=False)
    client = GraphClient()
    try:
        client.subscribe(Image, topics.IMAGE_TOPIC)
        client.subscribe(CameraInfo, topics.CAMERA_INFO_TOPIC)
        client.subscribe(PoseStamped, topics.ground_truth_topic('ape'))
        waits = [arg for topic in (topics.IMAGE_TOPIC, topics.CAMERA_INFO_TOPIC,
                                   topics.ground_truth_topic('ape'))
                 for arg in ('--wait-for', topic)]
        play = subprocess.Popen([sys.executable, '-m', 'bbpose_ros.cli.main', 'play', '--bag',
                                 str(bag), '--rate', '4', '--delay', '1', *waits],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        assert client.spin_until(lambda: len(client.received[topics.IMAGE_TOPIC]) == FRAMES
                                 and play.poll() is not None)
        stdout, stderr = play.communicate(timeout=60)
        assert play.returncode == 0, stderr
        assert 'published' in stdout
    finally:
        client.close()
    frames = read_bag_frames(bag)
    images = client.received[topics.IMAGE_TOPIC]
    assert [stamp_to_ns(m.header.stamp) for m in images] == [f.stamp_ns for f in frames]
    for message, frame in zip(images, frames):
        assert message.header.frame_id == frame.frame_id
        assert np.array_equal(image_to_rgb(message), frame.image_rgb)
    infos = client.received[topics.CAMERA_INFO_TOPIC]
    assert [stamp_to_ns(m.header.stamp) for m in infos] == [f.stamp_ns for f in frames]
    assert np.allclose(infos[0].k, frames[0].camera.k.reshape(-1))
    assert len(client.received[topics.ground_truth_topic('ape')]) == FRAMES


def test_the_player_sees_which_topics_wait_for_a_subscriber(lmo, tmp_path):
    use_private_domain(offset=2)
    bag = tmp_path / 'bag'
    write_bop_bag(lmo.frames()[:1], bag, rate_hz=20.0, progress=False)
    client = GraphClient()
    try:
        player = BagPlayer(client.node, bag)
        waiting = [topics.IMAGE_TOPIC, topics.CAMERA_INFO_TOPIC]
        assert player.unsubscribed(waiting) == waiting
        client.subscribe(Image, topics.IMAGE_TOPIC)
        assert client.spin_until(lambda: player.unsubscribed(waiting) ==
                                 [topics.CAMERA_INFO_TOPIC])
        with pytest.raises(InputError, match='/camera/nope'):
            player.unsubscribed(['/camera/nope'])
    finally:
        client.close()
