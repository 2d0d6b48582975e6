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
A lifecycle node's ``change_state`` service that answers an invalid transition as rclcpp does.

The pinned rclpy (7.1) raises RCLError out of the service callback when a transition asked
for by id is not one of the current state's (ros2/rclpy#1209, fixed upstream by #1319), and
the exception leaves the executor's spin: a lifecycle manager that configures an active
node by id takes it down. ``guard_change_state`` wraps the callback: such a request is
answered ``success=False`` with a log line naming the transitions the state has, and the
node keeps its state (rclcpp's behaviour). Requests by label already were.
"""

from collections.abc import Callable

from lifecycle_msgs.srv import ChangeState
from rclpy.impl.rcutils_logger import RcutilsLogger
from rclpy.lifecycle import LifecycleNode


def guard_change_state(node: LifecycleNode, logger: RcutilsLogger) -> None:
    """Make ``node``'s change_state service refuse an invalid transition id and live on."""
    service = node._service_change_state       # rclpy's own; no public hook (#1209)
    service.callback = guarded(service.callback, node, logger)


def guarded(callback: Callable[[ChangeState.Request, ChangeState.Response],
                               ChangeState.Response],
            node: LifecycleNode, logger: RcutilsLogger
            ) -> Callable[[ChangeState.Request, ChangeState.Response], ChangeState.Response]:
    """Return the change_state callback that checks a transition id before ``callback``."""
    def on_change_state(request: ChangeState.Request,
                        response: ChangeState.Response) -> ChangeState.Response:
        transition = request.transition
        if not transition.label:
            state, available = transitions_of(node)
            if transition.id not in available:
                logger.warning(
                    f'change_state refused: transition id {transition.id} is not one of '
                    f'state {state} ('
                    + ', '.join(f'{label} = {id_}' for id_, label in available.items())
                    + '); the node stays ' + state)
                response.success = False
                return response
        return callback(request, response)
    return on_change_state


def transitions_of(node: LifecycleNode) -> tuple[str, dict[int, str]]:
    """Return (the current state's label, {transition id: label} it has)."""
    machine = node._state_machine
    return machine.current_state[1], {
        transition[0]: transition[1] for transition in machine.available_transitions}
