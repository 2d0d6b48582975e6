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
Publish a rosbag2's messages into the ROS graph, as ``ros2 bag play`` does.

The bag is read with ``rosbags`` and each message is published as its raw CDR bytes, so
messages keep their recorded header stamps bit for bit.
"""

from collections.abc import Iterable, Iterator
import importlib
from pathlib import Path

from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import QoSProfile, QoSReliabilityPolicy
from rosbags.rosbag2 import Reader

from bbpose_ros.core.util.errors import InputError

PLAY_QOS = QoSProfile(depth=10, reliability=QoSReliabilityPolicy.RELIABLE)


def message_class(msgtype: str) -> type:
    """Return the rclpy message class of a type name such as 'sensor_msgs/msg/Image'."""
    package, _, name = msgtype.rpartition('/msg/')
    try:
        return getattr(importlib.import_module(f'{package}.msg'), name)
    except (ImportError, AttributeError) as err:
        raise InputError(f'message type {msgtype} is not installed') from err


class BagPlayer:
    """
    Publishers for the topics of a bag, and its messages in recorded order.

    Args:
        node: the rclpy Node that owns the publishers.
        path: rosbag2 folder (mcap or sqlite3).

    """

    def __init__(self, node: Node, path: Path | str) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise InputError(f'bag not found: {self.path}')
        try:
            with Reader(self.path) as reader:
                connections = {c.topic: c.msgtype for c in reader.connections}
                self.message_count = reader.message_count
        except Exception as err:  # rosbags raises its own error types for broken bags
            raise InputError(f'cannot open bag {self.path}: {err}') from err
        self.types = {topic: message_class(msgtype) for topic, msgtype in connections.items()}
        self.publishers = {topic: node.create_publisher(cls, topic, PLAY_QOS)
                           for topic, cls in self.types.items()}

    def messages(self) -> Iterator[tuple[str, int, bytes]]:
        """Yield (topic, recorded time in ns, raw CDR bytes) in recorded order."""
        with Reader(self.path) as reader:
            for connection, timestamp_ns, raw in reader.messages():
                yield connection.topic, timestamp_ns, bytes(raw)

    def publish(self, topic: str, raw: bytes) -> None:
        """Publish raw CDR bytes on a topic of the bag."""
        self.publishers[topic].publish(raw)

    def unsubscribed(self, topics: Iterable[str]) -> list[str]:
        """
        Return those of ``topics`` that no subscriber has matched yet.

        Raises InputError naming a topic the bag does not have.
        """
        missing = [topic for topic in topics if topic not in self.publishers]
        if missing:
            raise InputError(f'bag {self.path} has no topic {", ".join(missing)} '
                             f'(it has {", ".join(sorted(self.publishers))})')
        return [topic for topic in topics
                if self.publishers[topic].get_subscription_count() == 0]

    def wait_for_all_acked(self, timeout_s: float) -> bool:
        """Wait until subscribers acknowledged every message; returns False on timeout."""
        timeout = Duration(nanoseconds=int(timeout_s * 1e9))
        acked = [publisher.wait_for_all_acked(timeout) for publisher in self.publishers.values()]
        return all(acked)
