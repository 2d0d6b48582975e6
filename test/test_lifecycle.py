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
bbpose_node as a managed node, driven through its lifecycle and parameter services.

One node (``autostart: false``) serves the module; the tests run in file order, each
starting from the state the previous one left. In each state the transitions it does not
have are asked for by id: refused, and the node lives on in its state.
"""

import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
import pytest
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, QoSReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image
from test_ros_support import GraphClient, NodeLog, TIMEOUT_S, use_private_domain, weight_files
from test_ros_support import write_params
from visualization_msgs.msg import Marker, MarkerArray

from bbpose_ros.bags import topics
from bbpose_ros.cli.graph.graph_bench import camera_messages
from bbpose_ros.cli.graph.replay import NodeProcess
from bbpose_ros.core.data.stamps import stamp_to_ns
from bbpose_ros.ros.diagnostics import counts_from_status

pytestmark = pytest.mark.slow   # starts bbpose_node as a process

OUT = '/bbpose_node'
MARKERS = f'{OUT}/markers'
REPUBLISH_S = 2.0   # seconds between publications of a frame not answered yet
SECOND = 1_000_000_000
# The transitions by id: those each state does not have.
INVALID_IDS = {'unconfigured': (Transition.TRANSITION_CLEANUP, Transition.TRANSITION_ACTIVATE,
                                Transition.TRANSITION_DEACTIVATE),
               'inactive': (Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_DEACTIVATE),
               'active': (Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_ACTIVATE,
                          Transition.TRANSITION_CLEANUP),
               'finalized': (Transition.TRANSITION_CONFIGURE,
                             Transition.TRANSITION_UNCONFIGURED_SHUTDOWN)}


@pytest.fixture(scope='module')
def graph(lmo, lmo_root, tmp_path_factory):
    """Start the node unconfigured and a client; stop both at the end."""
    use_private_domain(offset=6)
    folder = tmp_path_factory.mktemp('lifecycle')
    log = NodeLog(folder / 'node.log')
    params = write_params(folder / 'params.yaml', lmo_root,
                          weight_files(folder), autostart=False)
    node = NodeProcess(params, stderr=log.file)
    client = GraphClient()
    client.image = client.publisher(Image, topics.IMAGE_TOPIC)
    client.info = client.publisher(CameraInfo, topics.CAMERA_INFO_TOPIC)
    client.subscribe(MarkerArray, MARKERS)
    client.subscribe(DiagnosticArray, '/diagnostics')
    client.pair = camera_messages(lmo.frames()[:1])[0]
    client.stamp_s = 1_700_000_000
    yield client, node, log
    client.close()
    node.stop()


def state(client):
    """
    Return the node's lifecycle state label, from its get_state service.

    Asked again when no answer comes (get_state changes nothing): a request sent while DDS
    is still matching the service's reply writer to this client may go unanswered.
    """
    for _ in range(3):
        response = client.call(GetState, f'{OUT}/get_state', GetState.Request(),
                               timeout_s=TIMEOUT_S / 3)
        if response is not None:
            return response.current_state.label
    return None


def transition(client, transition_id):
    """Ask for a transition; returns ChangeState's success."""
    request = ChangeState.Request(transition=Transition(id=transition_id))
    return client.call(ChangeState, f'{OUT}/change_state', request).success


def set_parameter(client, name, value):
    """Set one node parameter at run time; returns the SetParametersResult."""
    request = SetParameters.Request(parameters=[Parameter(name, value=value).to_parameter_msg()])
    return client.call(SetParameters, f'{OUT}/set_parameters', request).results[0]


def answered(client):
    """
    Publish a good frame with a new stamp; returns its MarkerArray (None if none came).

    The frame is published again every REPUBLISH_S until answered, as a camera streams: a
    first message sent while discovery is still matching the node's new subscription to
    this publisher may be dropped by DDS, which says nothing about the node.
    """
    client.stamp_s += 1
    image, info = client.pair
    for message in (image, info):
        message.header.stamp.sec, message.header.stamp.nanosec = client.stamp_s, 0
    stamp = stamp_to_ns(image.header.stamp)

    def answer():
        return next((m for m in client.received[MARKERS]
                     if stamp_to_ns(m.markers[0].header.stamp) == stamp), None)
    deadline = time.monotonic() + TIMEOUT_S
    while time.monotonic() < deadline:
        client.image.publish(image)
        client.info.publish(info)
        if client.spin_until(lambda: answer() is not None, timeout_s=REPUBLISH_S):
            break
    return answer()


def invalid_ids_refused(client, node, log):
    """Ask for each transition id the current state has not; each refused, state kept."""
    now = state(client)
    for transition_id in INVALID_IDS[now]:
        log.mark()
        assert not transition(client, transition_id), (now, transition_id)
        assert log.wait_for('WARN', 'change_state refused', f'id {transition_id}'), log.path
        assert state(client) == now
    node.check_alive()
    return True


def reported(markers):
    """Return the object names of a MarkerArray's boxes."""
    return {m.ns for m in markers.markers if m.type == Marker.LINE_LIST}


def latest_counts(client):
    """Return the counters of the latest /diagnostics received ({} before the first)."""
    messages = client.received['/diagnostics']
    return counts_from_status(messages[-1].status[0]) if messages else {}


def last_status(client, **expected):
    """Wait for a /diagnostics status whose values include ``expected``; return it."""
    def matching():
        for message in reversed(client.received['/diagnostics']):
            values = {v.key: v.value for v in message.status[0].values}
            if all(values.get(key) == value for key, value in expected.items()):
                return message.status[0]
        return None
    client.received['/diagnostics'].clear()
    client.spin_until(lambda: matching() is not None)
    return matching()


def test_starts_unconfigured_without_topics(graph):
    client, node, _ = graph
    assert state(client) == 'unconfigured'
    assert last_status(client, lifecycle_state='unconfigured') is not None
    assert client.image.get_subscription_count() == 0
    assert client.node.count_publishers(MARKERS) == 0
    node.check_alive()
    assert invalid_ids_refused(client, node, graph[2])


def test_a_failed_configure_gives_its_reason_and_stays_unconfigured(graph):
    client, node, log = graph
    assert set_parameter(client, 'objects', ['ape', 'teapot']).successful
    log.mark()
    assert not transition(client, Transition.TRANSITION_CONFIGURE)
    assert log.wait_for('ERROR', 'configure failed', 'teapot'), log.path
    assert state(client) == 'unconfigured'
    status = last_status(client, lifecycle_state='unconfigured')
    assert 'configure failed' in status.message and 'teapot' in status.message
    node.check_alive()


def test_configure_loads_and_makes_publishers_without_serving(graph):
    client, _, _ = graph
    assert set_parameter(client, 'objects', ['ape', 'can', 'glue']).successful
    assert transition(client, Transition.TRANSITION_CONFIGURE)
    assert state(client) == 'inactive'
    assert client.image.get_subscription_count() == 0
    # Lifecycle publishers exist from configure on; they publish once active.
    assert client.spin_until(lambda: client.node.count_publishers(MARKERS) == 1)
    assert client.received[MARKERS] == []
    assert invalid_ids_refused(client, *graph[1:])


def test_activate_serves_and_deactivate_stops(graph):
    client, _, _ = graph
    assert transition(client, Transition.TRANSITION_ACTIVATE)
    assert state(client) == 'active'
    assert client.connected((client.image,), MARKERS)
    assert answered(client)
    assert invalid_ids_refused(client, *graph[1:])
    assert transition(client, Transition.TRANSITION_DEACTIVATE)
    assert state(client) == 'inactive'
    assert client.spin_until(lambda: client.image.get_subscription_count() == 0)
    assert client.node.count_publishers(MARKERS) == 1
    # The last answer's boxes are cleared: nothing answers them any more.
    assert client.spin_until(lambda: [m.action for m in client.received[MARKERS][-1].markers]
                             == [Marker.DELETEALL])


def test_activate_again_after_deactivate(graph):
    client, _, _ = graph
    assert transition(client, Transition.TRANSITION_ACTIVATE)
    assert client.spin_until(lambda: client.image.get_subscription_count() > 0)
    assert answered(client)


def test_late_camera_infos_still_pair_their_images(graph):
    """5 Hz, each CameraInfo 0.25 s after its image (after the next image): none unpaired."""
    client, node, log = graph
    before = last_counts(client)
    image, info = client.pair
    client.stamp_s += 10
    stamps = [client.stamp_s * SECOND + k * SECOND // 5 for k in range(10)]
    events = sorted([(k * 0.2, 0, k) for k in range(10)]
                    + [(k * 0.2 + 0.25, 1, k) for k in range(10)])
    start = time.monotonic()
    for at_s, is_info, k in events:
        client.spin_until(lambda: time.monotonic() - start >= at_s, timeout_s=1.0)
        message = info if is_info else image
        message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamps[k], SECOND)
        (client.info if is_info else client.image).publish(message)
    client.stamp_s += 10

    def settled():
        counts = latest_counts(client)
        return counts.get('received', 0) >= before['received'] + 10 and \
            counts['answered'] + counts['superseded'] >= \
            before['answered'] + before['superseded'] + 10
    assert client.spin_until(settled), (before, latest_counts(client))
    assert latest_counts(client)['unpaired'] == before['unpaired']
    node.check_alive()


def last_counts(client):
    """Return the counters of the next /diagnostics status."""
    client.received['/diagnostics'].clear()
    client.spin_until(lambda: client.received['/diagnostics'])
    return latest_counts(client)


def test_a_starved_node_stays_warn_in_diagnostics(graph):
    """A publisher whose QoS keeps its images away: WARN in every report while it lasts."""
    client, node, _ = graph
    qos = QoSProfile(depth=1, reliability=QoSReliabilityPolicy.BEST_EFFORT)
    starved = client.node.create_publisher(Image, topics.IMAGE_TOPIC, qos)
    try:
        starved.publish(client.pair[0])
        client.received['/diagnostics'].clear()
        assert client.spin_until(lambda: any(
            m.status[0].level == DiagnosticStatus.WARN for m in client.received['/diagnostics']))
        first = next(k for k, m in enumerate(client.received['/diagnostics'])
                     if m.status[0].level == DiagnosticStatus.WARN)
        client.spin_until(lambda: False, timeout_s=6.0)
        levels = [m.status[0].level for m in client.received['/diagnostics'][first:]]
        assert len(levels) >= 5 and set(levels) == {DiagnosticStatus.WARN}, levels
        assert 'no image on' in client.received['/diagnostics'][-1].status[0].message
    finally:
        client.node.destroy_publisher(starved)
    assert answered(client)                     # images again: the reports recover
    client.received['/diagnostics'].clear()
    assert client.spin_until(lambda: any(m.status[0].level == DiagnosticStatus.OK
                                         for m in client.received['/diagnostics']))
    node.check_alive()


def set_and_rebuild(client, log, name, value):
    """Set a ``pipeline`` parameter and wait until the node has rebuilt its pipeline."""
    log.mark()
    assert set_parameter(client, name, value).successful
    assert log.wait_for('pipeline rebuilt for', name), log.path


def test_thresholds_and_objects_change_at_run_time(graph):
    client, _, log = graph
    set_and_rebuild(client, log, 'score_threshold', 1.0)
    assert reported(answered(client)) == set()
    set_and_rebuild(client, log, 'score_threshold', 0.0)
    assert reported(answered(client)) == {'ape', 'can', 'glue'}
    set_and_rebuild(client, log, 'objects', ['driller'])
    assert client.node.count_publishers(f'{OUT}/driller/pose') == 1
    assert reported(answered(client)) == {'driller'}


def test_a_bad_run_time_value_is_refused_with_its_reason(graph):
    client, node, log = graph
    before = counts_from_status(last_status(client, lifecycle_state='active'))[
        'parameters_refused']
    log.mark()
    for name, value, words in [('objects', ['teapot'], 'teapot'),
                               ('dataset_dir', '/tmp', 'while the node is unconfigured'),
                               ('score_threshold', 'high', 'Wrong parameter type'),
                               ('max_instances', 0, 'out of range'),
                               ('no_such_parameter', 1, 'does not exist')]:
        result = set_parameter(client, name, value)
        assert not result.successful and words in result.reason, result.reason
        assert log.wait_for('WARN', 'set refused', f'parameter {name}'), log.path
    assert client.spin_until(lambda: latest_counts(client).get('parameters_refused', 0)
                             >= before + 5)
    assert reported(answered(client)) == {'driller'}
    node.check_alive()


def test_cleanup_then_shutdown(graph):
    client, node, _ = graph
    assert transition(client, Transition.TRANSITION_DEACTIVATE)
    assert transition(client, Transition.TRANSITION_CLEANUP)
    assert state(client) == 'unconfigured'
    assert client.spin_until(lambda: client.node.count_publishers(MARKERS) == 0)
    assert last_status(client, lifecycle_state='unconfigured') is not None
    assert transition(client, Transition.TRANSITION_UNCONFIGURED_SHUTDOWN)
    assert state(client) == 'finalized'
    assert last_status(client, lifecycle_state='finalized') is not None
    assert invalid_ids_refused(client, *graph[1:])
