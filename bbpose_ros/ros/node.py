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
8-bit Bayer patterns) and ``camera_info`` (sensor_msgs/CameraInfo), paired by header stamp
within ``sync_slop``; a few images wait for a late CameraInfo (``pairing.StampPairer``).
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
  ``STALE_INPUT_S``.

The subscription callbacks only decode and pair; a worker thread runs the pipeline on the
newest pair, so frames arriving while it is busy replace each other instead of queueing. A
run-time set of a ``pipeline`` parameter is checked in the parameter callback and built by
``rebuild.PipelineRebuilder``, off the executor: the node keeps taking and answering frames
with the pipeline it has and swaps the new one in when it is ready (a build that fails sets
the parameters back and says why). An image stamped before the previous one (a bag
restarted, a camera reset) resets the tracker. An invalid lifecycle transition, or a set of
a parameter the node does not have, is refused with a reason and logged; the node lives on.
"""

from collections.abc import Sequence
from dataclasses import dataclass, field
import threading
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
import numpy as np
from rcl_interfaces.msg import SetParametersResult
import rclpy
from rclpy.event_handler import QoSRequestedIncompatibleQoSInfo, SubscriptionEventCallbacks
from rclpy.exceptions import ParameterException, ParameterNotDeclaredException
from rclpy.executors import ExternalShutdownException
from rclpy.lifecycle import LifecycleNode, LifecyclePublisher, LifecycleState
from rclpy.lifecycle import TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.qos import qos_profile_system_default, QoSPolicyKind
from rclpy.subscription import Subscription
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header
from tf2_msgs.msg import TFMessage
from vision_msgs.msg import Detection3DArray
from visualization_msgs.msg import MarkerArray

from bbpose_ros.core.data.models import bop_object_ids, names_source
from bbpose_ros.core.errors import InputError
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.camera_info import camera_model, Rectifier
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.pipeline.poses import PoseEstimate
from bbpose_ros.core.pipeline.tracking import PoseTracker
from bbpose_ros.core.stamps import BACKWARDS, REPEATED, stamp_to_ns, StampChecker
from bbpose_ros.core.viz import draw_estimates
from bbpose_ros.ros import conversions, detections
from bbpose_ros.ros.diagnostics import diagnostics_message, incompatible_qos_text, InputWatch
from bbpose_ros.ros.diagnostics import NodeStats
from bbpose_ros.ros.node_pipeline import build_node_pipeline, NodePipeline
from bbpose_ros.ros.pairing import LatestSlot, Pairing, StampPairer
from bbpose_ros.ros.params import check_value, checked_options, declare_parameters, NODE_NAME
from bbpose_ros.ros.params import NodeConfig, parameter_values, PARAMETERS, read_config
from bbpose_ros.ros.rebuild import PipelineRebuilder
from bbpose_ros.ros.throttle import KeyedThrottle
from bbpose_ros.ros.transitions import guard_change_state

DIAGNOSTICS_PERIOD_S = 1.0
# An image waiting longer for its CameraInfo is dropped. Longer than a reliable writer's
# repair of a lost sample (Fast DDS heartbeat period: 3 s), which a burst of large images
# can make a CameraInfo wait for; a newer image that pairs drops the older waiting ones.
UNPAIRED_TIMEOUT_S = 5.0
# While serving, no image for this long is a WARN condition in /diagnostics (a publisher
# with an incompatible QoS, a remap to the wrong topic, a camera that stopped).
STALE_INPUT_S = 3.0
# A stop waits this long for the worker to finish the frame in hand (one frame's work).
WORKER_JOIN_TIMEOUT_S = 5.0
# How far ahead of this node's clock an image stamp may be before it is reported: clocks of
# synchronised machines agree much better, a camera on its own clock is far off.
FUTURE_STAMP_TOLERANCE_NS = 1_000_000_000
SUCCESS = TransitionCallbackReturn.SUCCESS
FAILURE = TransitionCallbackReturn.FAILURE


@dataclass(frozen=True)
class SetVerdict:
    """
    What a parameter set comes to, judged once (``BBPoseNode._judge``).

    Attributes:
        names: the parameters set, in order.
        reason: why the set is refused, or None.
        changes: {name: value} of the ``pipeline`` parameters a rebuild must take.
        options: the PipelineOptions of every parameter's value with the set's.

    """

    names: tuple[str, ...]
    reason: str | None
    changes: dict[str, Any] = field(default_factory=dict)
    options: PipelineOptions | None = None


@dataclass(frozen=True)
class Frame:
    """
    A decoded image: its header, (H, W, 3) uint8 RGB pixels, perf_counter at receipt.

    ``stream`` counts the backward stamp jumps before it: frames of one stream follow
    each other in time, so a tracker resets when the stream changes.
    """

    header: Header
    image_rgb: np.ndarray
    received_s: float
    stream: int


class BBPoseNode(LifecycleNode):
    """
    The pose estimation node; ``configure`` builds the pipeline from its parameters.

    Args:
        **kwargs: passed to rclpy's LifecycleNode (e.g. parameter_overrides, context).

    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        declare_parameters(self)
        guard_change_state(self, self.get_logger())
        # Config and pipeline: set by configure, freed by cleanup, swapped by a rebuild.
        self._rebuilder = PipelineRebuilder(
            build=lambda config: build_node_pipeline(config, self.get_logger().info),
            set_back=self._set_back, log=self.get_logger().info,
            refuse=lambda names, text: self._warn('parameters_refused', names, text),
            reason=_reason)
        self.failure: str | None = None          # the reason of the last failed transition
        self.stats = NodeStats()
        self._watch = InputWatch(STALE_INPUT_S)
        self._throttle = KeyedThrottle()
        self._finalized = False                  # shut down: no transition leaves it
        # Lifecycle publishers: made by configure, enabled by activate.
        self._pose_pubs: dict[str, LifecyclePublisher] = {}
        self._markers_pub: LifecyclePublisher | None = None
        self._detections_pub: LifecyclePublisher | None = None
        self._tf_pub: LifecyclePublisher | None = None
        self._debug_pub: LifecyclePublisher | None = None
        # Made by activate, destroyed by deactivate.
        self._inputs: list[Subscription] = []
        self._worker: threading.Thread | None = None
        self._serving = False
        self._pairer = StampPairer()
        self._slot = LatestSlot()
        self._stamps = StampChecker(FUTURE_STAMP_TOLERANCE_NS)
        self._stream = 0                          # backward stamp jumps seen
        self._rectifier = Rectifier()             # the worker's
        self._frame_id = ''                       # of the last frame answered
        self._frame_ids_warned: set[tuple[str, str]] = set()
        self._diagnostics_pub: Publisher = self.create_publisher(
            DiagnosticArray, '/diagnostics', qos_profile_system_default)
        self.create_timer(DIAGNOSTICS_PERIOD_S, self._on_timer)
        self._verdict: SetVerdict | None = None   # of the set rclpy is making
        self.add_pre_set_parameters_callback(self._before_set_parameters)
        self.add_on_set_parameters_callback(self._on_set_parameters)

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Check the parameters, load the objects and networks, create the publishers."""
        try:
            config = read_config(parameter_values(self))
            pipeline = build_node_pipeline(config, self.get_logger().info)
        except Exception as err:  # noqa: B902 - a failed configure says why, whatever failed
            return self._fail('configure', _reason(err))
        self._rebuilder.install(config, pipeline)
        self.failure = None
        self._pose_pubs = {}
        self._add_pose_publishers(config.objects)
        self._markers_pub = self.create_lifecycle_publisher(MarkerArray, '~/markers', 10)
        self._detections_pub = self.create_lifecycle_publisher(
            Detection3DArray, detections.DETECTIONS_TOPIC, 10)
        self._tf_pub = self.create_lifecycle_publisher(TFMessage, detections.TF_TOPIC,
                                                       detections.TF_QOS)
        self._debug_pub = self.create_lifecycle_publisher(Image, '~/debug_image', 1)
        self.get_logger().info(f'configured: {", ".join(config.objects)}')
        return SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Enable the publishers; create the subscriptions and the worker thread."""
        enabled = super().on_activate(state)     # first: a frame answered is published
        if enabled != SUCCESS:
            return enabled
        self._pairer = StampPairer()
        self._slot = LatestSlot()
        self._stamps = StampChecker(FUTURE_STAMP_TOLERANCE_NS)
        self._frame_ids_warned = set()
        self._watch.start()
        self._inputs = [
            self.create_subscription(cls, topic, callback, self.config.qos,
                                     event_callbacks=self._input_events(topic))
            for cls, topic, callback in ((Image, 'image', self._on_image),
                                         (CameraInfo, 'camera_info', self._on_camera_info))]
        self._worker = threading.Thread(target=self._work, name='bbpose_worker', daemon=True)
        self._worker.start()
        self._serving = True
        self.get_logger().info(
            f'serving {", ".join(self.config.objects)} on {self._topic("image")} + '
            f'{self._topic("camera_info")} ({self.config.qos.reliability.name.lower()}, '
            f'depth {self.config.qos.depth})')
        return SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Stop taking frames, finish the current one, disable the publishers."""
        self._stop_serving()
        self.get_logger().info('inactive')
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Free the pipeline and the publishers; the parameters are read again at configure."""
        self._release()
        return SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Stop serving and free everything, from whichever state: finalized."""
        self._release()
        self._finalized = True
        return SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Stop serving and free everything; the node goes back to unconfigured."""
        self._release()
        return SUCCESS

    def destroy_node(self) -> None:
        """Stop the worker (waiting at most WORKER_JOIN_TIMEOUT_S), then the node."""
        self._release()
        super().destroy_node()

    def _fail(self, transition: str, err: str) -> TransitionCallbackReturn:
        self.failure = f'{transition} failed: {err}'
        self.get_logger().error(self.failure)
        return FAILURE

    @property
    def config(self) -> NodeConfig | None:
        """Return the parameters the current pipeline was built from (None: unconfigured)."""
        return self._rebuilder.config

    @property
    def pipeline(self) -> NodePipeline | None:
        """Return the NodePipeline in use (None: unconfigured)."""
        return self._rebuilder.pipeline

    def _release(self) -> None:
        """Stop serving, forget the pipeline (a rebuild under way is dropped), free topics."""
        self._stop_serving()
        self._rebuilder.release()
        publishers = [*self._pose_pubs.values(), self._markers_pub, self._detections_pub,
                      self._tf_pub, self._debug_pub]
        for publisher in publishers:
            if publisher is not None:
                self.destroy_lifecycle_publisher(publisher)
        self._pose_pubs = {}
        self._markers_pub = self._detections_pub = self._tf_pub = self._debug_pub = None

    def _stop_serving(self) -> None:
        if not self._serving:
            return
        self._serving = False
        for subscription in self._inputs:
            self.destroy_subscription(subscription)
        self._inputs = []
        self._watch.stop()
        self._slot.close()
        self._worker.join(WORKER_JOIN_TIMEOUT_S)
        if self.context.ok():       # the last boxes go from RViz: nothing answers them now
            header = Header(stamp=self.get_clock().now().to_msg(), frame_id=self._frame_id)
            self._markers_pub.publish(conversions.delete_all_markers(header))

    def _add_pose_publishers(self, names: Sequence[str]) -> None:
        """Create the pose publishers of new object names, enabled when serving."""
        added = {name: self.create_lifecycle_publisher(PoseStamped, f'~/{name}/pose', 10)
                 for name in names if name not in self._pose_pubs}
        if self._serving:
            for publisher in added.values():
                publisher.on_activate(None)     # rclpy's managed entities ignore the state
        self._pose_pubs = {**self._pose_pubs, **added}    # swapped whole: the worker reads it

    def _before_set_parameters(self, parameters: list[Parameter]) -> list[Parameter]:
        """
        Judge a set once, log and count a refusal; ``_on_set_parameters`` gives the verdict.

        rclpy calls this first, then checks the values against the descriptors (refusing
        there without calling ``_on_set_parameters``), so this is the one place that hears
        of every refusal, and the one check of each value and of their combination.
        """
        self._verdict = self._judge(parameters)
        if self._verdict.reason is not None:
            self._warn('parameters_refused', ' '.join(p.name for p in parameters),
                       f'set refused: {self._verdict.reason}')
        return parameters

    def _on_set_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        """Answer a set with its verdict; hand ``pipeline`` changes to the rebuild thread."""
        verdict, self._verdict = self._verdict, None
        if verdict is None or verdict.names != tuple(p.name for p in parameters):
            verdict = self._judge(parameters)       # not seen by the pre-set callback
        if verdict.reason is not None:
            return SetParametersResult(successful=False, reason=verdict.reason)
        if verdict.changes:
            self._add_pose_publishers(verdict.changes.get('objects', ()))
            self._rebuilder.request(verdict.changes, verdict.options)
        return SetParametersResult(successful=True)

    def _judge(self, parameters: list[Parameter]) -> SetVerdict:
        """
        Check a set: each value, then all values with the new ones as PipelineOptions.

        Everything that can be checked without building is checked here (the object names
        against the dataset too), so a set that is accepted rarely fails to build.
        """
        names = tuple(p.name for p in parameters)
        for parameter in parameters:
            reason = self._refusal(parameter)
            if reason is not None:
                return SetVerdict(names, reason)
        new = {p.name: p.value for p in parameters if p.name in PARAMETERS}
        try:
            options = checked_options({**parameter_values(self), **new})
            self._check_objects(new.get('objects'))
        except InputError as err:
            return SetVerdict(names, str(err))
        changes = self._rebuilder.needed({name: value for name, value in new.items()
                                          if PARAMETERS[name].applies == 'pipeline'})
        return SetVerdict(names, None, changes, options)

    def _check_undeclared_parameters(self, parameter_list: list[Parameter]) -> None:
        """
        Refuse a set of a parameter this node does not have, naming it.

        rclpy's check (which this overrides: it is the one rclpy asks) names none, an empty
        list; the reason goes back in the SetParametersResult.
        """
        for parameter in parameter_list:
            if not self.has_parameter(parameter.name):
                raise UnknownParameterError(self._refusal(parameter))
        super()._check_undeclared_parameters(parameter_list)

    def _refusal(self, parameter: Parameter) -> str | None:
        """Return why ``parameter``'s new value is refused now, or None."""
        if not self.has_parameter(parameter.name):
            return (f'parameter {parameter.name} does not exist: {self.get_name()} has '
                    f'{", ".join(PARAMETERS)}')
        spec = PARAMETERS.get(parameter.name)
        if spec is None:       # rclpy's own (use_sim_time)
            return None
        if spec.applies == 'start':
            return f'parameter {parameter.name} is read once at start (read-only)'
        if spec.applies == 'configure' and self.config is not None:
            return (f'parameter {parameter.name} is read by the configure transition: set it '
                    f'while the node is unconfigured (it is {self.lifecycle_state})')
        try:
            check_value(parameter.name, parameter.value)
        except InputError as err:
            return str(err)
        return None

    def _check_objects(self, names: Sequence[str] | None) -> None:
        """Raise InputError when object ``names`` (None: not set) are not in the dataset."""
        if names is None or self.config is None:
            return
        known = bop_object_ids(self.config.dataset_dir)
        unknown = [name for name in names if name not in known]
        if unknown:
            raise InputError(f'parameter objects: {", ".join(unknown)} not in '
                             f'{names_source(self.config.dataset_dir)} (known: '
                             f'{", ".join(known)})')

    def _set_back(self, values: dict[str, Any]) -> None:
        """Set parameters back to ``values`` ({name: value}): a failed rebuild's."""
        self.set_parameters([Parameter(name, value=value) for name, value in values.items()])

    @property
    def lifecycle_state(self) -> str:
        """Return 'unconfigured', 'inactive', 'active' or 'finalized'."""
        if self._finalized:
            return 'finalized'
        if self.config is None:
            return 'unconfigured'
        return 'active' if self._serving else 'inactive'

    def _input_events(self, topic: str) -> SubscriptionEventCallbacks:
        """Event callbacks of an input subscription: incompatible QoS is reported."""
        def on_incompatible_qos(event: QoSRequestedIncompatibleQoSInfo) -> None:
            text = incompatible_qos_text(
                self._topic(topic), QoSPolicyKind(event.last_policy_kind).name.lower(),
                self.get_parameter('qos_reliability').value)
            self._watch.incompatible(text)
            for _ in range(max(1, event.total_count_change)):
                self._warn('qos_incompatible', topic, text)
        return SubscriptionEventCallbacks(incompatible_qos=on_incompatible_qos)

    def _on_image(self, message: Image) -> None:
        self.stats.count('received')
        self._watch.image()
        received_s = time.perf_counter()
        header = message.header
        odd = self._stamps.check(stamp_to_ns(header.stamp),
                                 self.get_clock().now().nanoseconds)
        if odd is not None and odd[0] == REPEATED:
            self._warn(REPEATED, REPEATED,
                       f'image dropped (stamp {_stamp_text(header)}): {odd[1]}')
            return
        if odd is not None and odd[0] == BACKWARDS:
            self._stream += 1            # a new stream: what was tracked is of the old one
        if odd is not None:
            self._warn(odd[0], odd[0], f'image (stamp {_stamp_text(header)}) answered '
                       f'anyway: {odd[1]}')
        if not header.frame_id:
            self._warn('frame_id_empty', 'frame_id',
                       f'image (stamp {_stamp_text(header)}) answered anyway: header.frame_id '
                       f'is empty, so its poses name no frame (and no TF is published)')
        try:
            frame = Frame(header, conversions.image_to_rgb(
                message, self.get_parameter('max_image_pixels').value), received_s,
                self._stream)
        except InputError as err:
            self._drop('bad_image', str(err),
                       f'image dropped (stamp {_stamp_text(header)}): {err}')
            return
        self._take(self._pairer.add_image(stamp_to_ns(header.stamp), frame,
                                          self._sync_slop()))

    def _on_camera_info(self, message: CameraInfo) -> None:
        self._take(self._pairer.add_info(stamp_to_ns(message.header.stamp), message,
                                         self._sync_slop()))

    def _take(self, pairing: Pairing) -> None:
        """Drop the images the pairer gave up, then hand its pairs to the worker."""
        for frame, reason in pairing.dropped:
            self._drop_unpaired(frame, reason)
        for frame, info in pairing.pairs:
            self._hand_off(frame, info)

    def _hand_off(self, frame: Frame, info: CameraInfo) -> None:
        self._check_frame_ids(frame.header, info.header)
        height, width = frame.image_rgb.shape[:2]
        try:
            camera = camera_model(info, width, height, self.get_parameter('rectified').value)
        except InputError as err:
            self._drop('bad_camera_info', str(err),
                       f'image dropped (stamp {_stamp_text(frame.header)}): {err}')
            return
        if self._slot.put((frame, camera)) is not None:
            self.stats.count('superseded')

    def _check_frame_ids(self, image: Header, info: Header) -> None:
        """Count a pair whose frame_ids differ (usually a wrong remap); log each such pair once."""
        if image.frame_id == info.frame_id or not (image.frame_id and info.frame_id):
            return
        self.stats.count('frame_id_mismatch')
        if (image.frame_id, info.frame_id) not in self._frame_ids_warned:
            self._frame_ids_warned.add((image.frame_id, info.frame_id))
            self.get_logger().warning(
                f'image (stamp {_stamp_text(image)}) answered anyway: header.frame_id '
                f'"{image.frame_id}" differs from its camera_info\'s "{info.frame_id}" (a '
                f'wrong remap?); the poses are given in "{image.frame_id}"')

    def _on_timer(self) -> None:
        if self._serving:
            for frame in self._pairer.expire(UNPAIRED_TIMEOUT_S):
                self._drop_unpaired(frame, f'none came within {UNPAIRED_TIMEOUT_S} s')
        status = self.stats.status(f'{self.get_name()}: pose pipeline', self.lifecycle_state,
                                   self.failure, self._watch.conditions(self._topic('image')))
        self._diagnostics_pub.publish(
            diagnostics_message(self.get_clock().now().to_msg(), [status]))

    def _work(self) -> None:
        """Worker thread: estimate and publish the newest pair until the slot closes."""
        stream = self._stream
        while (item := self._slot.take()) is not None:
            frame, model = item
            pipeline = self.pipeline     # a run-time rebuild may swap it
            if frame.stream != stream and isinstance(pipeline.pipeline, PoseTracker):
                pipeline.pipeline.reset()
                self.get_logger().info('tracks reset: the image stamps went back')
            stream = frame.stream
            try:
                image_rgb = self._rectifier(frame.image_rgb, model)
                result = pipeline.pipeline.estimate(image_rgb, model.intrinsics)
                self._publish(frame.header, image_rgb, model.intrinsics, result.poses,
                              pipeline)
            except Exception as err:  # noqa: B902 - keep serving whatever one frame does
                if not self.context.ok():
                    return        # shutting down: the frame in hand is abandoned
                self._drop('failed', type(err).__name__,
                           f'estimation failed (stamp {_stamp_text(frame.header)}): '
                           f'{type(err).__name__}: {err}')
                continue
            self.stats.add_timings(
                dict(result.timings_ms, node=(time.perf_counter() - frame.received_s) * 1e3))
            self.stats.count('answered')

    def _publish(self, header: Header, image_rgb: np.ndarray, camera: CameraIntrinsics,
                 poses: Sequence[PoseEstimate], pipeline: NodePipeline) -> None:
        """Poses, detections, TF, then the markers that mark the frame answered, debug image."""
        stamped, markers = conversions.frame_messages(header, poses, pipeline.markers)
        prefix = detections.resolve_prefix(self.get_parameter('tf_prefix').value,
                                           self.get_fully_qualified_name())
        for name, message in stamped:
            self._pose_pubs[name].publish(message)
        # Made only for subscribers, as the debug image: rclpy messages are slow to build
        # (docs/experiments.md).
        pose_msgs = [message.pose for _, message in stamped]
        if self._detections_pub.get_subscription_count() > 0:
            self._detections_pub.publish(pipeline.detections(header, poses, pose_msgs, prefix))
        if poses and header.frame_id and self.get_parameter('publish_tf').value and \
                self._tf_pub.get_subscription_count() > 0:
            self._tf_pub.publish(detections.transforms(header, poses, pose_msgs, prefix))
        self._markers_pub.publish(markers)
        self._frame_id = header.frame_id
        if self.get_parameter('publish_debug_image').value and \
                self._debug_pub.get_subscription_count() > 0:
            self._debug_pub.publish(conversions.rgb_to_image(
                header, draw_estimates(image_rgb, camera, pipeline.pipeline.models, poses)))

    def _drop_unpaired(self, frame: Frame, reason: str) -> None:
        offset_s = self._pairer.nearest_offset_s(stamp_to_ns(frame.header.stamp))
        if offset_s is None:
            key, problem = 'none', f'no {self._topic("camera_info")} received yet'
        else:
            key, problem = 'offset', (
                f'no {self._topic("camera_info")} with a stamp within sync_slop = '
                f'{self._sync_slop()} s; the nearest differs by {offset_s:.3f} s')
        self._warn('unpaired', key,
                   f'image dropped (stamp {_stamp_text(frame.header)}): {problem} ({reason})')

    def _warn(self, counter: str, key: str, text: str) -> None:
        """Count ``counter``; log ``text`` as a warning, throttled per (counter, key)."""
        self.stats.count(counter)
        if self._throttle.allow(f'{counter}:{key}'):
            self.get_logger().warning(text)

    def _drop(self, counter: str, key: str, text: str) -> None:
        """Count a frame dropped for bad input; log ``text`` as an error, throttled."""
        self.stats.count(counter)
        if self._throttle.allow(f'{counter}:{key}'):
            self.get_logger().error(text)

    def _sync_slop(self) -> float:
        return self.get_parameter('sync_slop').value

    def _topic(self, name: str) -> str:
        return self.resolve_topic_name(name)


class UnknownParameterError(ParameterNotDeclaredException):
    """A set of a parameter the node does not have; its text is the reason given back."""

    def __init__(self, reason: str) -> None:
        Exception.__init__(self, reason)    # rclpy's own text names no parameter


def _reason(err: BaseException) -> str:
    """Return an exception as a reason: an InputError's message names the problem already."""
    return str(err) if isinstance(err, InputError) else f'{type(err).__name__}: {err}'


def _stamp_text(header: Header) -> str:
    return f'{header.stamp.sec}.{header.stamp.nanosec:09d}'


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
