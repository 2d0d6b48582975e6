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

"""The vision_msgs and tf2_msgs that make builds (interfaces/) are the official Jazzy types."""

import json
from pathlib import Path

from ament_index_python.packages import get_package_share_directory
from geometry_msgs.msg import TransformStamped
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from tf2_msgs.msg import TFMessage
from vision_msgs.msg import Detection3D, Detection3DArray, ObjectHypothesisWithPose

INTERFACES = Path(__file__).parents[1] / 'interfaces'

# RIHS01 type hashes of ROS 2 Jazzy's own packages: a subscriber of a full ROS install
# matches this node's topics only when they are equal.
OFFICIAL_HASHES = {
    'tf2_msgs/msg/TFMessage':
        'RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087',
    'vision_msgs/msg/Detection3DArray':
        'RIHS01_793f5eab9595ac1c0da07873cc859db42eae51f0ee76056db8562515d830e018',
}


def type_hashes(package, message):
    """Return {type name: RIHS01 hash} of a message's generated type description."""
    path = Path(get_package_share_directory(package)) / 'msg' / f'{message}.json'
    return {entry['type_name']: entry['hash_string']
            for entry in json.loads(path.read_text())['type_hashes']}


@pytest.mark.parametrize('type_name', sorted(OFFICIAL_HASHES))
def test_type_hash_is_the_official_one(type_name):
    package, _, message = type_name.split('/')
    assert type_hashes(package, message)[type_name] == OFFICIAL_HASHES[type_name]


def test_every_interface_file_is_installed():
    for definition in INTERFACES.glob('*/msg/*.msg'):
        package = definition.parents[1].name
        installed = Path(get_package_share_directory(package)) / 'msg' / definition.name
        assert installed.read_text() == definition.read_text(), f'{installed}: run make setup'


def test_messages_round_trip_through_cdr():
    array = Detection3DArray(detections=[Detection3D(
        results=[ObjectHypothesisWithPose()], id='x')])
    array.header.frame_id = 'cam'
    array.detections[0].results[0].hypothesis.class_id = 'ape'
    array.detections[0].bbox.size.z = 0.05
    assert deserialize_message(serialize_message(array), Detection3DArray) == array
    tf = TFMessage(transforms=[TransformStamped(child_frame_id='ape')])
    tf.transforms[0].transform.rotation.w = 1.0
    assert deserialize_message(serialize_message(tf), TFMessage) == tf
