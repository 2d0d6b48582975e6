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

"""``bbpose play``: publish a bag's topics into the ROS graph (``ros2 bag play`` stand-in)."""

import argparse
from pathlib import Path
import time

import rclpy
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from bbpose_ros.bags.player import BagPlayer
from bbpose_ros.core.util.errors import InputError

ACK_TIMEOUT_S = 5.0   # reliable messages still in flight when the bag ends
SUBSCRIBER_POLL_S = 0.05   # how often --wait-for looks at the graph


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the ``play`` subcommand."""
    parser = subparsers.add_parser(
        'play', help='publish the topics of a rosbag2 with their recorded stamps',
        description='Publish every message of a rosbag2 (mcap or sqlite3) on its topic, '
                    'raw and unchanged (header stamps as recorded), paced by the recorded '
                    'times divided by --rate.')
    parser.add_argument('--bag', type=Path, required=True, help='rosbag2 folder to play')
    parser.add_argument('--rate', type=float, default=1.0,
                        help='playback speed factor (default %(default)s)')
    parser.add_argument('--delay', type=float, default=1.0,
                        help='seconds to let subscribers discover the publishers before the '
                             'first message (default %(default)s)')
    parser.add_argument('--wait-for', metavar='TOPIC', action='append', default=[],
                        help='before the delay, wait until this topic of the bag has a '
                             'subscriber (repeatable; as `ros2 topic pub -w`, no time limit)')
    parser.set_defaults(func=run)


def wait_for_subscribers(player: BagPlayer, topics: list[str]) -> None:
    """Block until each of the bag's ``topics`` has a subscriber, saying which it waits for."""
    waiting = player.unsubscribed(topics)
    if waiting:
        print(f'waiting for subscribers on {", ".join(waiting)}', flush=True)
    while waiting:
        time.sleep(SUBSCRIBER_POLL_S)
        waiting = player.unsubscribed(waiting)


def play(player: BagPlayer, rate: float, delay_s: float = 0.0) -> int:
    """Publish the bag's messages paced by recorded time / rate; returns the count."""
    time.sleep(delay_s)
    start_s, first_ns, count = time.perf_counter(), None, 0
    for topic, time_ns, raw in player.messages():
        first_ns = time_ns if first_ns is None else first_ns
        wait_s = start_s + (time_ns - first_ns) * 1e-9 / rate - time.perf_counter()
        if wait_s > 0:
            time.sleep(wait_s)
        player.publish(topic, raw)
        count += 1
    return count


def run(args: argparse.Namespace) -> int:
    """Play the bag; returns the exit code."""
    if args.rate <= 0:
        raise InputError(f'--rate must be positive, got {args.rate}')
    # Python's own SIGINT handling, so Ctrl-C stops the loop with KeyboardInterrupt.
    rclpy.init(args=[], signal_handler_options=SignalHandlerOptions.NO)
    node = Node('bbpose_play')
    try:
        player = BagPlayer(node, args.bag)
        print(f'playing {player.message_count} messages on {len(player.publishers)} topics '
              f'from {args.bag} at rate {args.rate}')
        wait_for_subscribers(player, args.wait_for)
        count = play(player, args.rate, args.delay)
        delivered = player.wait_for_all_acked(ACK_TIMEOUT_S)
        print(f'published {count} messages' + ('' if delivered else
              f' (some not acknowledged by reliable subscribers within {ACK_TIMEOUT_S} s)'))
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
