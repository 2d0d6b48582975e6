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
The node's lifecycle transitions: what each does to the node's parts, and the state left.

``NodeTransitions`` holds the steps, in the shape of ros2/demos' ``lifecycle_py``:
``configure`` checks the parameters, builds the pipeline and creates the (lifecycle)
publishers, and a failure is a failed transition, its reason logged and kept for
/diagnostics; ``activate`` (once rclpy has enabled the publishers) starts the worker and
the subscriptions; ``deactivate`` undoes that (and stops stream mode's background job);
``release`` (cleanup, shutdown, error) also
frees the pipeline and the publishers.

The pinned rclpy (7.1) raises RCLError out of the ``change_state`` service callback when a
transition asked for by id is not one of the current state's (ros2/rclpy#1209, fixed
upstream by #1319), and the exception leaves the executor's spin: a lifecycle manager that
configures an active node by id takes it down. ``guard_change_state`` wraps the callback:
such a request is answered ``success=False`` with a log line naming the transitions the
state has, and the node keeps its state (rclcpp's behaviour). Requests by label already
were.
"""

from collections.abc import Callable, Sequence

from lifecycle_msgs.srv import ChangeState
from rclpy.impl.rcutils_logger import RcutilsLogger
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn

from bbpose_ros.core.util.errors import InputError
from bbpose_ros.ros.intake import FrameIntake
from bbpose_ros.ros.node_pipeline import NodePipeline, stop_background
from bbpose_ros.ros.params import NodeConfig, parameter_values, read_config
from bbpose_ros.ros.publishers import FramePublishers
from bbpose_ros.ros.rebuild import PipelineRebuilder
from bbpose_ros.ros.scene_mapping import SceneMapping
from bbpose_ros.ros.worker import FrameWorker

SUCCESS = TransitionCallbackReturn.SUCCESS
FAILURE = TransitionCallbackReturn.FAILURE


class NodeTransitions:
    """
    The steps of each lifecycle transition, and the state they leave the node in.

    Args:
        node: the node whose transitions these are.
        rebuilder: holds the config and pipeline that configure makes.
        publishers: created by configure, destroyed by release.
        intake: subscribes on activate, unsubscribes on deactivate.
        worker: started on activate, stopped on deactivate.
        build: makes the NodePipeline of a NodeConfig; raises on failure.
        mapping: the map in ``fixed_frame``: made by configure, listens to TF while active.

    """

    def __init__(self, node: LifecycleNode, rebuilder: PipelineRebuilder,
                 publishers: FramePublishers, intake: FrameIntake, worker: FrameWorker,
                 build: Callable[[NodeConfig], NodePipeline], mapping: SceneMapping) -> None:
        self._node = node
        self._rebuilder = rebuilder
        self._publishers = publishers
        self._intake = intake
        self._worker = worker
        self._build = build
        self._mapping = mapping
        self.failure: str | None = None          # the reason of the last failed transition
        self._serving = False
        self._finalized = False                  # shut down: no transition leaves it

    @property
    def state(self) -> str:
        """Return 'unconfigured', 'inactive', 'active' or 'finalized'."""
        if self._finalized:
            return 'finalized'
        if self._rebuilder.config is None:
            return 'unconfigured'
        return 'active' if self._serving else 'inactive'

    def configure(self) -> TransitionCallbackReturn:
        """Check the parameters, load the objects and networks, create the publishers."""
        try:
            config = read_config(parameter_values(self._node))
            pipeline = self._build(config)
        except Exception as err:  # noqa: B902 - a failed configure says why, whatever failed
            self.failure = f'configure failed: {failure_reason(err)}'
            self._node.get_logger().error(self.failure)
            return FAILURE
        self._rebuilder.install(config, pipeline)
        self.failure = None
        self._publishers.create(config.objects)
        self._mapping.create(config.objects)
        self._node.get_logger().info(f'configured: {", ".join(config.objects)}')
        return SUCCESS

    def activate(self) -> TransitionCallbackReturn:
        """Start the worker and the subscriptions; the publishers are enabled already."""
        config = self._rebuilder.config
        self._worker.start(self._intake.stream)
        self._intake.subscribe(config.qos, config.image_transport)
        self._mapping.subscribe()
        self._serving = True
        self._node.get_logger().info(
            f'serving {", ".join(config.objects)} on {self._intake.image_topic} + '
            f'{self._intake.topic("camera_info")} ({config.qos.reliability.name.lower()}, '
            f'depth {config.qos.depth})')
        return SUCCESS

    def deactivate(self) -> None:
        """Stop taking frames, finish the current one; rclpy disables the publishers."""
        self._stop_serving()
        self._node.get_logger().info('inactive')

    def release(self) -> None:
        """Stop serving, forget the pipeline (a rebuild under way is dropped), free topics."""
        self._stop_serving()
        stop_background(self._rebuilder.pipeline, for_good=True)
        self._rebuilder.release()
        self._publishers.destroy()
        self._mapping.destroy()

    def shut_down(self) -> None:
        """Release everything, from whichever state: finalized."""
        self.release()
        self._finalized = True

    def expire_unpaired(self) -> None:
        """Drop the images that waited too long for a CameraInfo (while serving)."""
        if self._serving:
            self._intake.expire()

    def add_objects(self, names: Sequence[str]) -> None:
        """Create the pose publishers of object names a parameter set adds."""
        self._publishers.add_objects(names, enabled=self._serving)
        self._mapping.add_objects(names, enabled=self._serving)

    def _stop_serving(self) -> None:
        if not self._serving:
            return
        self._serving = False
        self._intake.unsubscribe()
        self._worker.stop()
        self._mapping.unsubscribe()
        stop_background(self._rebuilder.pipeline)     # stream mode's background job
        if self._node.context.ok():   # the last boxes go from RViz: nothing answers them now
            self._publishers.clear_markers()


def failure_reason(err: BaseException) -> str:
    """Return an exception as a reason: an InputError's message names the problem already."""
    return str(err) if isinstance(err, InputError) else f'{type(err).__name__}: {err}'


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
