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
``bbpose_node``: Image + CameraInfo in; poses, markers, a debug image and diagnostics out.

A managed (lifecycle) node in the shape of ros2/demos' ``lifecycle_py``: every attribute is
declared in ``__init__``; ``configure`` checks the parameters, loads the objects and the
networks and creates the (lifecycle) publishers (a failure is a failed transition, its
reason logged, and the node stays unconfigured); ``activate`` enables the publishers and
creates the subscriptions and the worker; ``deactivate`` undoes that; ``cleanup`` frees the
pipeline and the publishers. With ``autostart`` (default) the node configures and activates
itself at start and exits with code 1 when it cannot. ``/diagnostics`` is published in
every state.

Subscriptions: ``image`` (sensor_msgs/Image: rgb8, bgr8, rgba8, bgra8, mono8 and the four
8-bit Bayer patterns; with ``image_transport: compressed``, image_transport's
``image/compressed`` instead: sensor_msgs/CompressedImage, JPEG or PNG, decoded by the
worker) and ``camera_info`` (sensor_msgs/CameraInfo), paired by header stamp within
``sync_slop``; a few images wait for a late CameraInfo (``pairing.StampPairer``).
Publications, stamped with the image's header (stamp and frame_id):

* ``~/<object>/pose`` (geometry_msgs/PoseStamped, metres, ROS quaternion order), one per
  instance found, for each configured object;
* ``~/detections`` (vision_msgs/Detection3DArray), once per answered frame while it has
  subscribers, one Detection3D per pose;
* ``/tf`` (tf2_msgs/TFMessage), with ``publish_tf`` and while it has subscribers: one
  transform per pose, image frame -> ``<tf_prefix><object>`` (``detections.frame_names``;
  the default prefix ``~/`` is the node's name);
* ``~/markers`` (visualization_msgs/MarkerArray), once per answered frame, and one
  DELETEALL when the node stops answering;
* ``~/debug_image`` (sensor_msgs/Image rgb8), only while it has subscribers;
* ``/diagnostics`` (diagnostic_msgs/DiagnosticArray) at 1 Hz, WARN while no image came for
  ``intake.STALE_INPUT_S``;
* with ``fixed_frame`` set, the map of the scene in that frame, fused over the camera's
  motion from TF: ``~/map/detections``, ``~/map/<object>/pose``, ``~/map/markers`` and
  ``/tf``, and the service ``~/clear_map`` (``scene_mapping.py``).

The subscription callbacks only check, decode and pair (``intake.py``); a worker thread
(``worker.py``) runs the pipeline on the newest pair, so frames arriving while it is busy
replace each other instead of queueing, and publishes (``publishers.py``). A run-time set
of a ``pipeline`` parameter is checked in the parameter callback (``verdicts.py``) and built
by ``rebuild.PipelineRebuilder``, off the executor: the node keeps taking and answering
frames with the pipeline it has and swaps the new one in when it is ready (a build that
fails sets the parameters back and says why). An image stamped before the previous one (a
bag restarted, a camera reset) resets the tracker. An invalid lifecycle transition
(``transitions.py``), or a set of a parameter the node does not have, is refused with a
reason and logged; the node lives on.
"""

from collections.abc import Sequence
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.qos import qos_profile_system_default

from bbpose_ros.ros.diagnostics import diagnostics_message, NodeStats
from bbpose_ros.ros.intake import FrameIntake
from bbpose_ros.ros.node_pipeline import build_node_pipeline, NodePipeline
from bbpose_ros.ros.params import declare_parameters, NODE_NAME, NodeConfig
from bbpose_ros.ros.publishers import FramePublishers
from bbpose_ros.ros.rebuild import PipelineRebuilder
from bbpose_ros.ros.scene_mapping import SceneMapping
from bbpose_ros.ros.throttle import ProblemLog
from bbpose_ros.ros.transitions import failure_reason, guard_change_state, NodeTransitions
from bbpose_ros.ros.transitions import SUCCESS
from bbpose_ros.ros.verdicts import ParameterVerdicts
from bbpose_ros.ros.worker import FrameWorker

DIAGNOSTICS_PERIOD_S = 1.0


class BBPoseNode(LifecycleNode):
    """
    The pose estimation node; ``configure`` builds the pipeline from its parameters.

    The node only wires its parts together: ``NodeTransitions`` (what each lifecycle
    transition does), ``ParameterVerdicts`` (run-time parameter sets), ``FrameIntake`` (the
    subscriptions and their checks), ``FrameWorker`` (the pipeline thread) and
    ``FramePublishers`` (its outputs), ``SceneMapping`` (TF and the map in
    ``fixed_frame``), with ``PipelineRebuilder`` holding the pipeline.

    Args:
        **kwargs: passed to rclpy's LifecycleNode (e.g. parameter_overrides, context).

    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        declare_parameters(self)
        guard_change_state(self, self.get_logger())
        # The parts; rclpy's Node keeps _publishers and _subscriptions of its own.
        self.stats = NodeStats()
        self._problems = ProblemLog(self.stats.count, self.get_logger())
        # Config and pipeline: set by configure, freed by cleanup, swapped by a rebuild.
        self._rebuilder = PipelineRebuilder(
            build=self._build, set_back=self._set_back, log=self.get_logger().info,
            refuse=lambda names, text: self._problems.warn('parameters_refused', names, text),
            reason=failure_reason)
        self._outputs = FramePublishers(self)
        self._mapping = SceneMapping(self, self._problems, self.stats.count)
        self._worker = FrameWorker(lambda: self._rebuilder.pipeline, self._outputs,
                                   self.stats, self._problems, self.get_logger(), self.context,
                                   decode=lambda frame, info: self._intake.decode(frame, info),
                                   mapping=self._mapping)
        self._intake = FrameIntake(self, self.stats, self._problems, self._worker.offer)
        self._transitions = NodeTransitions(self, self._rebuilder, self._outputs,
                                            self._intake, self._worker, self._build,
                                            self._mapping)
        self._verdicts = ParameterVerdicts(self, self._rebuilder, self._problems,
                                           self._transitions.add_objects,
                                           lambda: self._transitions.state)
        self._diagnostics_pub: Publisher = self.create_publisher(
            DiagnosticArray, '/diagnostics', qos_profile_system_default)
        self.create_timer(DIAGNOSTICS_PERIOD_S, self._on_timer)
        self.add_pre_set_parameters_callback(self._verdicts.before_set)
        self.add_on_set_parameters_callback(self._verdicts.on_set)

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Check the parameters, load the objects and networks, create the publishers."""
        return self._transitions.configure()

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Enable the publishers; create the subscriptions and the worker thread."""
        enabled = super().on_activate(state)     # first: a frame answered is published
        if enabled != SUCCESS:
            return enabled
        return self._transitions.activate()

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Stop taking frames, finish the current one, disable the publishers."""
        self._transitions.deactivate()
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Free the pipeline and the publishers; the parameters are read again at configure."""
        self._transitions.release()
        return SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Stop serving and free everything, from whichever state: finalized."""
        self._transitions.shut_down()
        return SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Stop serving and free everything; the node goes back to unconfigured."""
        self._transitions.release()
        return SUCCESS

    def destroy_node(self) -> None:
        """Stop the worker (``worker.WORKER_JOIN_TIMEOUT_S`` at most), then the node."""
        self._transitions.release()
        super().destroy_node()

    @property
    def failure(self) -> str | None:
        """Return the reason of the last failed transition (None: it succeeded)."""
        return self._transitions.failure

    @property
    def lifecycle_state(self) -> str:
        """Return 'unconfigured', 'inactive', 'active' or 'finalized'."""
        return self._transitions.state

    @property
    def config(self) -> NodeConfig | None:
        """Return the parameters the current pipeline was built from (None: unconfigured)."""
        return self._rebuilder.config

    @property
    def pipeline(self) -> NodePipeline | None:
        """Return the NodePipeline in use (None: unconfigured)."""
        return self._rebuilder.pipeline

    def _build(self, config: NodeConfig) -> NodePipeline:
        """Build the pipeline of ``config`` (configure, and a rebuild), logging its networks."""
        return build_node_pipeline(config, self.get_logger().info)

    def _set_back(self, values: dict[str, Any]) -> None:
        """Set parameters back to ``values`` ({name: value}): a failed rebuild's."""
        self.set_parameters([Parameter(name, value=value) for name, value in values.items()])

    def _check_undeclared_parameters(self, parameter_list: list[Parameter]) -> None:
        """
        Refuse a set of a parameter this node does not have, naming it.

        rclpy's check (which this overrides: it is the one rclpy asks) names none, an empty
        list; the reason goes back in the SetParametersResult.
        """
        self._verdicts.check_declared(parameter_list)
        super()._check_undeclared_parameters(parameter_list)

    def _on_timer(self) -> None:
        self._transitions.expire_unpaired()
        status = self.stats.status(f'{self.get_name()}: pose pipeline', self.lifecycle_state,
                                   self.failure, self._intake.conditions())
        self._diagnostics_pub.publish(
            diagnostics_message(self.get_clock().now().to_msg(), [status]))


def main(args: Sequence[str] | None = None) -> int:
    """Run the node until SIGINT / SIGTERM; returns 0, or 1 when it cannot start."""
    rclpy.init(args=args)
    try:
        node = BBPoseNode()
    except ParameterException as err:
        rclpy.logging.get_logger(NODE_NAME).fatal(f'cannot start: {err}')
        rclpy.try_shutdown()
        return 1
    if node.get_parameter('autostart').value and (
            node.trigger_configure() != SUCCESS or node.trigger_activate() != SUCCESS):
        node.get_logger().fatal(f'cannot start (autostart): {node.failure}')
        node.destroy_node()
        rclpy.try_shutdown()
        return 1
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:  # noqa: B902 - a signal's shutdown may land mid-wait: an RCLError
        if rclpy.ok():
            raise
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
