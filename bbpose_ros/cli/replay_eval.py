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
``bbpose replay-eval``: replay a bag through ``bbpose_node`` and score what it publishes.

The node runs as a child process; the bag is played in lockstep or, with ``--paced``, at
its recorded rate (see ``graph.replay``); the node's outputs are recorded into a results bag
beside the JSON, and its poses (those of the PoseStamped topics, and separately those of
``~/detections``) are scored against the bag's ground truth by ``core.eval.recorded_poses``
with the scoring code of ``bbpose eval``, one instance record each beside the report.
``--video`` writes each frame's estimates beside its ground truth as an .mp4. A bag of
compressed images (``make-bag --compressed``) is played to a node started with
``image_transport:=compressed`` (``with_transport``).
"""

import argparse
from collections import Counter
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
import sys
from typing import Any

import numpy as np
import rclpy
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from std_srvs.srv import Trigger
from tqdm import tqdm
import yaml

from bbpose_ros.bags import topics
from bbpose_ros.bags.player import BagPlayer
from bbpose_ros.bags.reader import bag_image_source, BagFrame, read_bag_frames
from bbpose_ros.bags.writer import write_bag
from bbpose_ros.cli.graph.replay import DEFAULT_PARAMS, NODE_NAME, NodeProcess, Recorder
from bbpose_ros.cli.graph.replay import replay_bag, use_large_image_profile
from bbpose_ros.core.data.models import load_bop_models, ObjectModel
from bbpose_ros.core.eval import plots
from bbpose_ros.core.eval.instance_scores import InstanceScore, summarize_objects
from bbpose_ros.core.eval.paired import write_instances
from bbpose_ros.core.eval.recorded_poses import ground_truth_instances, map_in_cameras
from bbpose_ros.core.eval.recorded_poses import Recording, recording_report
from bbpose_ros.core.eval.recorded_poses import score_recording
from bbpose_ros.core.eval.tables import format_report
from bbpose_ros.core.eval.video import check_video_path, write_video
from bbpose_ros.core.pipeline import overlays
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.core.util.files import write_json_atomic, write_rgb_png
from bbpose_ros.ros.params import resolve_dataset_dir
from bbpose_ros.ros.params_file import read_params_file

OVERLAY_FRAMES = 4
# How long a replay waits for the node's map of a frame, and for ~/clear_map to answer.
MAP_WAIT_S = 10.0


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the ``replay-eval`` subcommand."""
    parser = subparsers.add_parser(
        'replay-eval', help='replay a bag through bbpose_node and score its poses',
        description='Start bbpose_node, play a bag made by make-bag (raw or --compressed '
                    'images: the node gets the image_transport to match) into it (each frame '
                    'after the previous one is answered, the node per frame: stream mode is '
                    'for --paced), record its outputs into a results '
                    'bag beside --json, and score its poses against the ground truth of the bag '
                    'like bbpose eval (same table and JSON keys, instance records beside it for '
                    'bbpose compare, plus frames sent/answered '
                    'and timing_ms.end_to_end: image published -> pose received, '
                    'timing_ms.answer: image published -> MarkerArray received). With '
                    '--param fixed_frame:=world and a bag with camera poses on /tf (make-bag of '
                    "bbpose static-scenes output), the node's map (~/map/detections) is scored "
                    "too, in each frame's camera by the bag's /tf, the map cleared where a "
                    'new static scene begins: R.map.json and its instance records.')
    parser.add_argument('--bag', type=Path, required=True, help='bag with ground truth')
    parser.add_argument('--json', type=Path, required=True, help='report to write')
    parser.add_argument('--plots', type=Path, default=None,
                        help='folder for PNG charts and overlay images')
    parser.add_argument('--params', type=Path, default=DEFAULT_PARAMS,
                        help='parameters file of the node (default %(default)s)')
    parser.add_argument('--video', type=Path, default=None, metavar='FILE.mp4',
                        help="video of every replayed frame: the node's poses beside the "
                             'ground truth')
    parser.add_argument('--video-fps', type=float, default=5.0,
                        help='frames per second of --video (default %(default)s)')
    parser.add_argument('--param', action='append', default=[], metavar='NAME:=VALUE',
                        help='override one node parameter (repeatable)')
    parser.add_argument('--answer-timeout', type=float, default=30.0,
                        help='seconds to wait for the answer to each frame '
                             '(default %(default)s)')
    parser.add_argument('--paced', action='store_true',
                        help="play each message at its recorded time (the bag's rate), as a "
                             'camera streams, instead of each frame after the previous '
                             'answer: frames the node drops are scored as missed')
    parser.add_argument('--compare-tracking', action='store_true',
                        help='replay a second time with the node parameter tracking flipped '
                             "and report both runs' means and latencies under 'tracking'")
    parser.set_defaults(func=run)


def map_report_path(json_path: Path) -> Path:
    """Where the map's report of R.json goes: R.map.json (its instances beside it)."""
    return json_path.with_name(f'{json_path.stem}.map.json')


def scene_starts(frames: Sequence[BagFrame], fixed_frame: str, bag: Path) -> list[int] | None:
    """
    Stamps of the frames that begin a static scene, with a map (``fixed_frame``); else None.

    Raises InputError when the node maps but the bag holds no camera poses in its frame.
    """
    if not fixed_frame:
        return None
    if fixed_frame != topics.FIXED_FRAME or all(f.world_from_camera is None for f in frames):
        raise InputError(f'fixed_frame {fixed_frame!r}: bag {bag} has no camera poses in it '
                         f'on /tf ({topics.FIXED_FRAME} -> the camera; bbpose make-bag writes '
                         'them from frames with cam_R_w2c / cam_t_w2c)')
    return [f.stamp_ns for k, f in enumerate(frames)
            if k == 0 or f.scene != frames[k - 1].scene]


def results_bag_path(json_path: Path) -> Path:
    """Return the results bag folder beside the report: ``<stem>_results_bag``."""
    return json_path.with_name(f'{json_path.stem}_results_bag')


def write_plots(folder: Path, frames: Sequence[BagFrame], recording: Recording,
                models: Mapping[str, ObjectModel], scores: Mapping[str, Sequence[InstanceScore]],
                per_object: Mapping[str, Mapping[str, float]]) -> None:
    """Write the recall curves, per-object bars and a few overlay images into ``folder``."""
    plots.recall_curves(scores, folder / 'recall_curves.png')
    plots.object_bars(per_object, folder / 'objects.png')
    for index in np.linspace(0, len(frames) - 1, min(OVERLAY_FRAMES, len(frames))).astype(int):
        frame = frames[index]
        truths = [(i.object_name, i.rotation, i.translation)
                  for i in ground_truth_instances(frame, models)]
        image = overlays.draw_comparison(frame.image_rgb, frame.camera, models, truths,
                                         recording.poses.get(frame.stamp_ns, []))
        write_rgb_png(folder / f'overlay_{index:04d}.png', image)


def video_frames(frames: Sequence[BagFrame], recording: Recording,
                 models: Mapping[str, ObjectModel]) -> Iterator[np.ndarray]:
    """Yield per frame its PoseStamped estimates (left) beside its ground truth (right)."""
    for index, frame in enumerate(frames):
        estimates = recording.poses.get(frame.stamp_ns, [])
        truths = [(i.object_name, i.rotation, i.translation)
                  for i in ground_truth_instances(frame, models)]
        yield overlays.side_by_side([
            (overlays.draw_comparison(frame.image_rgb, frame.camera, models, [], estimates),
             f'bbpose_node: {len(estimates)} poses (frame {index})'),
            (overlays.draw_comparison(frame.image_rgb, frame.camera, models, [], truths),
             f'ground truth: {len(truths)} objects')])


def with_transport(overrides: Sequence[str], transport: str) -> list[str]:
    """
    Return parameter ``overrides`` and ``image_transport:=<transport>``: the bag's images.

    A bag of compressed images (``make-bag --compressed``) is played to a node subscribed
    to them; an override that sets another transport is an InputError.
    """
    for override in overrides:
        name, _, text = override.partition(':=')
        if name.strip() == 'image_transport' and yaml.safe_load(text) != transport:
            raise InputError(f'--param {override}: the bag holds {transport} images '
                             f'(image_transport:={transport})')
    return list(overrides) + [f'image_transport:={transport}']


def per_frame_in_lockstep(overrides: Sequence[str], values: Mapping[str, Any]) -> list[str]:
    """
    Return parameter ``overrides`` for a lock-step replay: stream mode off.

    Stream mode answers a frame from the tracks before its detection ends; played in lock
    step, each frame follows that answer at once, and the detections never catch up with
    the frames (a camera's frames come at its rate: ``--paced``). ``values``: the node's
    parameters with the overrides; one that asks for stream mode is an InputError.
    """
    if any(o.partition(':=')[0].strip() == 'tracking_stream' for o in overrides) and \
            values['tracking_stream']:
        raise InputError('--param tracking_stream:=true needs --paced: a lock-step replay '
                         'sends each frame as soon as the previous one is answered')
    return list(overrides) + ['tracking_stream:=false']


def record(args: argparse.Namespace, objects: list[str], frame_count: int,
           overrides: list[str], image_topic: str = topics.IMAGE_TOPIC,
           scene_starts: Sequence[int] | None = None) -> Recording:
    """
    Run the node with parameter ``overrides``, replay the bag into it; return the Recording.

    ``image_topic``: the bag's image topic (a compressed one needs the node's
    ``image_transport`` compressed among the overrides: ``with_transport``).
    ``scene_starts``: with a map (``fixed_frame``), the stamps of the images where a new
    static scene begins: the node's ``~/clear_map`` is called before each (but the first).
    """
    use_large_image_profile()
    rclpy.init(args=[], signal_handler_options=SignalHandlerOptions.NO)
    node = Node('bbpose_replay_eval')
    process = NodeProcess(args.params, overrides)
    try:
        player = BagPlayer(node, args.bag)
        recorder = Recorder(node, objects, scene_map=scene_starts is not None)
        before_image = None if scene_starts is None else \
            MapClearing(node, recorder, process, set(scene_starts))
        with tqdm(total=frame_count, desc='replaying', unit='frame') as bar:
            recording = replay_bag(player, recorder, process, args.paced,
                                   image_topic=image_topic,
                                   answer_timeout_s=args.answer_timeout,
                                   progress=lambda sent: bar.update(sent - bar.n),
                                   before_image=before_image)
    finally:
        code = process.stop()
        node.destroy_node()
        rclpy.try_shutdown()
    if code != 0:
        print(f'bbpose replay-eval: warning: bbpose_node exited with code {code} on SIGINT',
              file=sys.stderr)
    return recording


class MapClearing:
    """
    Clears the node's map before the images that start a new static scene.

    Before clearing, the previous image's map is waited for (briefly: a frame TF could not
    place has none), so that no view of one scene lands in the next scene's map.
    """

    def __init__(self, node: Node, recorder: Recorder, process: NodeProcess,
                 starts: set[int]) -> None:
        self._client = node.create_client(Trigger, f'/{NODE_NAME}/clear_map')
        self._recorder = recorder
        self._process = process
        self._starts = starts
        self._previous: int | None = None

    def __call__(self, stamp_ns: int) -> None:
        """Clear the map if the image of ``stamp_ns`` starts a scene (not the first)."""
        previous, self._previous = self._previous, stamp_ns
        if previous is None or stamp_ns not in self._starts:
            return
        recorder = self._recorder
        recorder.spin_until(lambda: previous in recorder.recording.map_detections,
                            MAP_WAIT_S, self._process)
        if not self._client.wait_for_service(timeout_sec=MAP_WAIT_S):
            raise InputError(f'{NODE_NAME} offers no ~/clear_map service')
        future = self._client.call_async(Trigger.Request())
        recorder.spin_until(future.done, MAP_WAIT_S, self._process)


def unscored_poses(recording: Recording, objects: Mapping[str, Mapping]) -> dict[str, int]:
    """
    Return {object: poses the node published} for the objects without ground truth.

    ``objects``: the report's per-object figures (``n``: ground-truth instances), e.g. an
    object added with ``bbpose add-object`` replayed on a bag of LM-O frames.
    """
    published = Counter(name for poses in recording.poses.values() for name, _, _ in poses)
    return {name: published[name] for name, figures in objects.items() if figures['n'] == 0}


def run(args: argparse.Namespace) -> int:
    """Replay, score, print the table and write the JSON, bag and plots; returns 0."""
    if args.video is not None:
        check_video_path(args.video)
    values = read_params_file(args.params, args.param)
    models = load_bop_models(resolve_dataset_dir(values['dataset_dir']), values['objects'])
    frames = read_bag_frames(args.bag)
    if not frames or any(frame.camera is None for frame in frames):
        raise InputError(f'bag {args.bag} has no frames or a frame without camera_info')
    image_topic, transport = bag_image_source(args.bag)
    overrides = with_transport(args.param, transport)
    if not args.paced:
        if values['tracking_stream']:
            print(f'bbpose replay-eval: {args.params} sets tracking_stream; a lock-step '
                  'replay runs the node per frame (stream mode: --paced)', file=sys.stderr)
        overrides = per_frame_in_lockstep(overrides, values)
    starts = scene_starts(frames, values['fixed_frame'], args.bag)
    recording = record(args, list(models), len(frames), overrides, image_topic, starts)
    bag_path = results_bag_path(args.json)
    write_bag(bag_path, recording.messages, replace=True)
    scores = score_recording(frames, recording.poses, models)
    report = recording_report(recording, scores,
                              score_recording(frames, recording.detections, models))
    if starts is not None:
        map_scores = score_recording(frames, map_in_cameras(frames, recording.map_detections),
                                     models)
        map_path = map_report_path(args.json)
        map_report = dict(summarize_objects(map_scores), frames=report['frames'],
                          mapped=len(recording.map_detections))
        write_instances(map_path, map_scores)
        write_json_atomic(map_path, map_report)
        report['map'] = {'mean': map_report['mean'], 'mapped': map_report['mapped'],
                         'report': str(map_path)}
    if args.compare_tracking:
        tracking = bool(values['tracking'])
        flipped = record(args, list(models), len(frames),
                         overrides + [f'tracking:={str(not tracking).lower()}',
                                      'tracking_stream:=false'], image_topic)
        other = recording_report(flipped, score_recording(frames, flipped.poses, models),
                                 score_recording(frames, flipped.detections, models))
        report['tracking'] = {
            'on' if run_tracking else 'off': {key: run[key] for key in
                                              ('mean', 'timing_ms', 'frames')}
            for run_tracking, run in ((tracking, report), (not tracking, other))}
    report['config'] = {'bag': str(args.bag), 'params': str(args.params),
                        'param_overrides': overrides, 'image_transport': transport,
                        'paced': args.paced,
                        'results_bag': str(bag_path)}
    print(format_report(report))
    for name, count in unscored_poses(recording, report['objects']).items():
        print(f'{name}: no ground truth in the bag, {count} poses published (not scored)')
    print(f'frames: {report["frames"]["sent"]} sent, {report["frames"]["answered"]} answered')
    if 'map' in report:
        mean = report['map']['mean']
        print(f'~/map/detections ({report["map"]["mapped"]} frames mapped), in each '
              f'camera by the bag\'s /tf: ADD(-S) {mean["add_s_recall"]:.3f}, 5cm5deg '
              f'{mean["cm5deg5"]:.3f}, proj5px {mean["proj5px"]:.3f} '
              f'(report: {report["map"]["report"]})')
    detections = report['detections']
    print(f'~/detections: {detections["arrays"]} arrays, {detections["detections"]} '
          f'detections, ADD(-S) {detections["mean"]["add_s_recall"]:.3f}, 5cm5deg '
          f'{detections["mean"]["cm5deg5"]:.3f}; /tf: {detections["tf_transforms"]} '
          f'transforms')
    for mode, run in report.get('tracking', {}).items():
        mean, answer = run['mean'], run['timing_ms'].get('answer', {})
        print(f'tracking {mode}: ADD(-S) {mean["add_s_recall"]:.3f}, 5cm5deg '
              f'{mean["cm5deg5"]:.3f}, answer latency median '
              f'{answer.get("median_ms", float("nan")):.1f} ms, p95 '
              f'{answer.get("p95_ms", float("nan")):.1f} ms')
    records = write_instances(args.json, scores)
    write_json_atomic(args.json, report)
    print(f'report written to {args.json} (instances: {records}), node outputs to {bag_path}')
    if args.plots is not None:
        write_plots(args.plots, frames, recording, models, scores, report['objects'])
        print(f'plots written to {args.plots}')
    if args.video is not None:
        count = write_video(args.video, video_frames(frames, recording, models), args.video_fps)
        print(f'video of {count} frames written to {args.video}')
    return 0
