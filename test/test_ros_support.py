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
Helpers of the graph tests (no tests here): weights, parameter files, a client, node logs.

Each test module gets its own ROS domain on the loopback only, so test runs never see each
other; waits are bounded by generous timeouts, never asserted on.
"""

from collections import defaultdict
import os
from pathlib import Path
import time

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
import torch

from bbpose_ros.core.data.models import LMO_OBJECTS
from bbpose_ros.core.inference.weights import DEFAULT_DETECTOR_WEIGHTS, DEFAULT_QNET_WEIGHTS
from bbpose_ros.core.inference.weights import save_weights
from bbpose_ros.core.nets.detector import CenterBoxNet, DetectorConfig
from bbpose_ros.core.nets.qnet import QNet, QNetConfig

REPO_ROOT = Path(__file__).resolve().parents[1]
TIMEOUT_S = 60.0   # bound of every wait; a healthy run takes a fraction of it


# The domain the run was started in, read once: use_private_domain changes the variable.
BASE_DOMAIN = os.environ.get('ROS_DOMAIN_ID')


def use_private_domain(offset):
    """
    Put this process (and its children) on a ROS domain of its own, loopback only.

    The domain is the run's ROS_DOMAIN_ID + ``offset`` when it was given one (``make test``
    draws one; parallel runs on one machine pass their own, a few apart), else
    100 + (pid + ``offset``) % 100. Each test module has its own ``offset``.
    """
    domain = int(BASE_DOMAIN) + offset if BASE_DOMAIN else 100 + (os.getpid() + offset) % 100
    os.environ['ROS_DOMAIN_ID'] = str(domain)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ['RCUTILS_LOGGING_BUFFERED_STREAM'] = '0'
    os.environ['PYTHONPATH'] = os.pathsep.join(
        p for p in (str(REPO_ROOT), os.environ.get('PYTHONPATH')) if p)


def weight_files(folder):
    """Return (detector, qnet) files: the shipped ones, else seeded random networks."""
    if DEFAULT_DETECTOR_WEIGHTS.is_file() and DEFAULT_QNET_WEIGHTS.is_file():
        return DEFAULT_DETECTOR_WEIGHTS, DEFAULT_QNET_WEIGHTS
    torch.manual_seed(0)
    objects = tuple(LMO_OBJECTS)
    detector, qnet = Path(folder) / 'detector.pt', Path(folder) / 'qnet.pt'
    save_weights(detector, CenterBoxNet(DetectorConfig(objects)), 'detector', {'test': 1})
    save_weights(qnet, QNet(QNetConfig(objects)), 'qnet', {'test': 1})
    return detector, qnet


def write_params(path, dataset, weights, **values):
    """Write a node parameters file: dataset, weights, score threshold 0 and ``values``."""
    values = dict({'dataset_dir': str(dataset), 'detector_weights': str(weights[0]),
                   'qnet_weights': str(weights[1]), 'score_threshold': 0.0}, **values)
    lines = [f'    {name}: {value!r}' for name, value in values.items()]
    Path(path).write_text('/**:\n  ros__parameters:\n' + '\n'.join(lines) + '\n')
    return path


class NodeLog:
    """The node's stderr in a file, read as it grows."""

    def __init__(self, path):
        self.path = Path(path)
        self.file = self.path.open('w')
        self._offset = 0

    def mark(self):
        """Forget what was logged so far: ``wait_for`` then looks only at newer lines."""
        self._offset = len(self.path.read_text())

    def wait_for(self, *words, timeout_s=TIMEOUT_S):
        """Return the first new line holding all ``words`` (None on timeout)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for line in self.path.read_text()[self._offset:].splitlines():
                if all(word in line for word in words):
                    return line
            time.sleep(0.05)
        return None


class GraphClient:
    """A node in its own context that publishes inputs and records outputs by topic."""

    def __init__(self, name='bbpose_test_client'):
        self.context = Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.received = defaultdict(list)
        self.clients = {}

    def publisher(self, cls, topic):
        """Create a reliable publisher."""
        return self.node.create_publisher(cls, topic, 10)

    def subscribe(self, cls, topic):
        """Record the messages of a topic into ``received[topic]``."""
        self.node.create_subscription(cls, topic, self.received[topic].append, 100)

    def matched(self):
        """Return True when every subscription of this client has matched a publisher."""
        return all(s.get_publisher_count() > 0 for s in self.node.subscriptions)

    def spin_until(self, done, timeout_s=TIMEOUT_S):
        """Spin until ``done()``; returns whether it became true within the timeout."""
        deadline = time.monotonic() + timeout_s
        while not done():
            if time.monotonic() > deadline:
                return False
            self.executor.spin_once(timeout_sec=0.02)
        return True

    def connected(self, inputs, output):
        """Spin until the node subscribes to the ``inputs`` publishers and publishes ``output``."""
        return self.spin_until(lambda: all(p.get_subscription_count() > 0 for p in inputs)
                               and self.node.count_publishers(output) > 0)

    def call(self, srv_type, name, request, timeout_s=TIMEOUT_S):
        """Call service ``name`` once it is there; returns the response (None on timeout)."""
        client = self.clients.get(name)
        if client is None:
            client = self.clients[name] = self.node.create_client(srv_type, name)
        if not self.spin_until(client.service_is_ready, timeout_s):
            return None
        future = client.call_async(request)
        self.spin_until(future.done, timeout_s)
        return future.result()

    def close(self):
        """Destroy the node and shut the context down."""
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
