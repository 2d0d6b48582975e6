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

"""``bbpose eval``: score the pipeline on a BOP dataset folder and write the report JSON."""

from __future__ import annotations

import argparse
from collections.abc import Mapping, Sequence
import dataclasses
from pathlib import Path
from typing import Any, TYPE_CHECKING

from bbpose_ros.cli.common import (add_blocks_argument, add_dataset_argument,
                                   add_frames_argument, add_objects_argument, float_pair,
                                   in_blocks)
from bbpose_ros.cli.settings_options import (add_settings_options, PIPELINE_TITLE,
                                             settings_made)
from bbpose_ros.core.data.bop import BopDataset, BopFrame
from bbpose_ros.core.eval.detection import format_detection_report, score_detections
from bbpose_ros.core.eval.evaluation import estimate_frames, score_poses
from bbpose_ros.core.eval.fusion import format_map_tracks, frame_camera_poses, FUSE_MODES
from bbpose_ros.core.eval.fusion import fused_poses, map_track_report
from bbpose_ros.core.eval.instance_scores import InstanceScore, make_report
from bbpose_ros.core.eval.paired import write_instances
from bbpose_ros.core.eval.tables import format_report
from bbpose_ros.core.geometry.rotations import PERTURB_DIRECTIONS
from bbpose_ros.core.inference.options import PipelineOptions, SETTINGS
from bbpose_ros.core.pipeline.loader import load_pipeline, StagesGiven, WeightFiles
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.core.util.files import write_json_atomic

if TYPE_CHECKING:
    from bbpose_ros.core.data.models import ObjectModel
    from bbpose_ros.core.pipeline.pose_pipeline import PosePipeline
    from bbpose_ros.core.pipeline.tracking import PoseTracker


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the ``eval`` subcommand."""
    parser = subparsers.add_parser(
        'eval', help='evaluate the pipeline on BOP frames (table + JSON)',
        description='Run the pipeline on the frames of a BOP dataset and score it: ADD(-S), '
                    '5 cm / 5 deg, 2D projection, rotation and translation errors per object. '
                    '--boxes gt and --rotation gt replace the learned stages by the ground '
                    'truth, to isolate the Bounding Box Equation. With --boxes detector the '
                    'report also scores the detector (recall and AP at IoU 0.5).')
    add_dataset_argument(parser)
    parser.add_argument('--split', default='test',
                        help="the dataset's split folder to score, e.g. train_synth (what "
                             "bbpose synth writes) or your own frames' (default %(default)s)")
    parser.add_argument('--boxes', choices=('gt', 'detector'), default='detector',
                        help='2D boxes from the ground truth (amodal bbox_obj) or the detector')
    parser.add_argument('--rotation', choices=('gt', 'qnet'), default='qnet',
                        help='rotations from the ground truth or from Q-Net')
    parser.add_argument('--detector-weights', type=Path, default=None,
                        help='detector weight file (default: the shipped one)')
    parser.add_argument('--qnet-weights', type=Path, default=None,
                        help='Q-Net weight file (default: the shipped one)')
    parser.add_argument('--dense-weights', type=Path, default=None,
                        help='dense net weight file (default: the shipped one)')
    parser.add_argument('--perturb-gt', type=float_pair, action='append', default=None,
                        metavar='DEG,MM',
                        help='with --boxes gt --rotation gt: start each pose from the ground '
                             'truth turned DEG degrees about a random axis and moved MM '
                             'millimetres (see --perturb-direction), then refine it (the '
                             "refiner's basin). Repeat it for a sweep: the report is the "
                             "first level's, with every level's means under 'sweep', and "
                             '--plots draws refinement_basin.png')
    parser.add_argument('--perturb-direction', choices=PERTURB_DIRECTIONS, default='random',
                        help='how --perturb-gt moves the truth: in a random direction, or '
                             'along the viewing ray (towards or away from the camera, as a '
                             "box of the wrong size moves the Bounding Box Equation's "
                             'translation; default %(default)s)')
    parser.add_argument('--seed', type=int, default=0,
                        help='seed of the --perturb-gt perturbations (default %(default)s)')
    parser.add_argument('--fuse', choices=FUSE_MODES, default='none',
                        help="score each frame's own poses (none), or the map of its scene: "
                             'built from the frames up to it (causal) or from the whole scene '
                             '(final). Each BOP scene is one static scene; its '
                             'scene_camera.json must hold the camera poses (cam_R_w2c, '
                             'cam_t_w2c: bbpose static-scenes writes them). The map reads '
                             'images and camera poses, never the ground truth (default '
                             '%(default)s)')
    parser.add_argument('--camera-noise', type=float_pair, default=None, metavar='MM,DEG',
                        help='with --fuse: add a TF-like error to each camera pose first (RMS '
                             'MM millimetres, DEG degrees; seeded by --seed): the sensitivity '
                             'of the map to it; the map_camera_sigma_* settings say what the '
                             'map assumes (default: none)')
    add_objects_argument(parser)
    add_frames_argument(parser)
    add_blocks_argument(parser)
    parser.add_argument('--min-visib', type=float, default=0.1,
                        help='count instances at least this visible (default %(default)s)')
    parser.add_argument('--json', type=Path, default=None,
                        help='write the report here, and one record per instance beside it '
                             '(R.instances.json, for bbpose compare)')
    parser.add_argument('--plots', type=Path, default=None,
                        help='write charts into this folder: recall curves, per-object '
                             'recalls, errors by visible fraction, what a minimum confidence '
                             'keeps')
    parser.add_argument('--params', type=Path, default=None,
                        help="the node's parameters file (e.g. bbpose adapt's or add-object's "
                             'params.yaml): its weight files and settings, under the options '
                             'given here')
    parser.add_argument('--skip-adapted', action='store_true',
                        help='leave out the frames the weights adapted on (bbpose adapt); '
                             'without it, scoring them is refused')
    add_settings_options(parser, PipelineOptions, PIPELINE_TITLE, names=EVAL_SETTINGS)
    parser.set_defaults(func=run)


# Every setting but tracking, which follows poses from frame to frame of a camera stream.
EVAL_SETTINGS = tuple(name for name in SETTINGS if not name.startswith('tracking'))


def build_pipeline(models: Mapping[str, ObjectModel], args: argparse.Namespace,
                   params: Mapping[str, Any], weights: WeightFiles) -> PosePipeline | PoseTracker:
    """
    Build the pipeline of the options over ``params``; ground-truth stages are not loaded.

    ``params`` are the node parameter values of ``--params`` ({} without it), ``weights``
    the files ``weight_files`` chose.
    """
    options = settings_made(PipelineOptions, args,
                            {name: params[name] for name in EVAL_SETTINGS if name in params})
    return load_pipeline(models, options, weights,
                         StagesGiven(boxes=args.boxes == 'gt', rotations=args.rotation == 'gt'))


def params_values(path: Path | None) -> dict[str, Any]:
    """Return the node parameter values of a parameters file ({} without one)."""
    if path is None:
        return {}
    from bbpose_ros.ros.params_file import read_params_file
    return read_params_file(path)


def weight_files(args: argparse.Namespace, params: Mapping[str, Any]) -> WeightFiles:
    """Return the weight files of the options, else of ``params``, else the shipped ones."""
    return WeightFiles(*(getattr(args, f'{kind}_weights') or
                         (Path(params[f'{kind}_weights']) if params.get(f'{kind}_weights')
                          else None) for kind in ('detector', 'qnet', 'dense')))


def without_adapted(frames: Sequence[BopFrame], weights: WeightFiles,
                    skip: bool) -> list[BopFrame]:
    """
    Refuse, or with ``skip`` leave out, the frames the weight files adapted on.

    A frame is recognised by its pixels (``adaptation.frames.image_fingerprint``), wherever
    it is read from. Raises InputError naming the first such frame without ``skip``.
    """
    from bbpose_ros.core.adaptation.adapt_stages import adapted_frames
    from bbpose_ros.core.adaptation.frames import image_fingerprint
    adapted = set()
    for kind in ('detector', 'qnet'):
        path = getattr(weights, kind)
        if path is not None:
            adapted |= adapted_frames(path, kind)
    if not adapted:
        return list(frames)
    seen = [f for f in frames if image_fingerprint(f.load_image()) in adapted]
    if seen and not skip:
        raise InputError(f'the weights adapted on {len(seen)} of these frames (first: '
                         f'{seen[0].image_path}); scoring them would flatter the weights. '
                         'Score other frames, or pass --skip-adapted to leave them out')
    if seen:
        print(f'left out {len(seen)} frames the weights adapted on (--skip-adapted)')
    return [f for f in frames if f not in seen]


class RecordingDetector:
    """
    A detector callable that keeps the detections of each call, in call order.

    With ``--boxes detector``, ``evaluate`` calls the pipeline's detector exactly once per
    frame, in frame order, so what this records lines up with the frames and the detection
    metrics need no second detector pass.
    """

    def __init__(self, detector):
        self.detector = detector
        self.calls = []

    def __call__(self, image_rgb):
        """Detect with the wrapped detector and record the result."""
        detections = self.detector(image_rgb)
        self.calls.append(detections)
        return detections


def _weights_name(path):
    return 'shipped' if path is None else str(path)


def run(args: argparse.Namespace) -> int:
    """Evaluate, print the table(s) and write the JSON; returns the exit code."""
    dataset = BopDataset(args.dataset, args.split)
    models = dataset.load_models(args.objects)
    params = params_values(args.params)
    weights = weight_files(args, params)
    frames = in_blocks(dataset.frames(), args.blocks, args.block_size)[:args.max_frames]
    frames = without_adapted(frames, weights, args.skip_adapted)
    if not frames:
        raise InputError(f'no frames to score in {args.dataset / args.split}')
    levels = args.perturb_gt or [None]
    if args.perturb_gt is not None and (args.boxes != 'gt' or args.rotation != 'gt'):
        raise InputError('--perturb-gt needs --boxes gt --rotation gt')
    camera_poses = None
    if args.fuse != 'none':
        camera_poses = frame_camera_poses(frames, args.camera_noise, args.seed)
    elif args.camera_noise is not None:
        raise InputError('--camera-noise needs --fuse causal or final')
    pipeline = build_pipeline(models, args, params, weights)
    recorder = None
    if args.boxes == 'detector':
        recorder = pipeline.detector = RecordingDetector(pipeline.detector)
    sweep = []
    for level in levels:
        perturb = None if level is None else (level[0], level[1] / 1000.0)
        results = estimate_frames(
            frames, pipeline, boxes=args.boxes,
            rotation='gt' if args.rotation == 'gt' else 'estimator', min_visib=args.min_visib,
            perturb=perturb, seed=args.seed, perturb_direction=args.perturb_direction)
        poses, timings = [r.poses for r in results], [r.timings_ms for r in results]
        if camera_poses is not None:
            run = fused_poses(frames, poses, camera_poses, pipeline.models, pipeline.options,
                              args.fuse)
            poses = run.poses
            timings = [dict(t, map=ms) for t, ms in zip(timings, run.map_ms)]
        level_scores = score_poses(frames, poses, pipeline.models, args.min_visib)
        level_report = make_report(level_scores, timings, len(frames))
        if level is not None:
            sweep.append({'deg': level[0], 'mm': level[1], 'mean': level_report['mean']})
        if len(sweep) <= 1:
            report, scores = level_report, level_scores
            if camera_poses is not None:
                # The truth carried into the world by the poses without the added error.
                report['map'] = map_track_report(frames, frame_camera_poses(frames), run)
    if len(sweep) > 1:
        report['sweep'] = sweep
    detection = None
    if recorder is not None:
        pipeline.detector = recorder.detector
        detection = score_detections(frames, recorder.calls, list(models), args.min_visib)
        report['detection'] = {**detection['detection'], 'mean': detection['mean']}
    report['config'] = {'dataset': str(args.dataset), 'split': args.split,
                        'boxes': args.boxes,
                        'rotation': args.rotation, 'min_visib': args.min_visib,
                        'params': None if args.params is None else str(args.params),
                        **{f'{kind}_weights': _weights_name(getattr(weights, kind))
                           for kind in ('detector', 'qnet', 'dense')},
                        **dataclasses.asdict(pipeline.options),
                        'detector_network': getattr(pipeline.detector, 'precision', None),
                        'qnet_network': getattr(pipeline.rotation_estimator, 'precision',
                                                None),
                        'perturb_gt_deg_mm': args.perturb_gt,
                        'perturb_direction': args.perturb_direction, 'seed': args.seed,
                        'fuse': args.fuse, 'camera_noise_mm_deg': args.camera_noise}
    print(format_report(report))
    if 'map' in report:
        print(format_map_tracks(report['map']))
    for level in report.get('sweep', []):
        mean = level['mean']
        print(f'start {level["deg"]:g} deg / {level["mm"]:g} mm: 5cm5deg {mean["cm5deg5"]:.3f}, '
              f'ADD(-S) {mean["add_s_recall"]:.3f}, rotation median '
              f'{mean["re_median_deg"]:.1f} deg')
    if detection is not None:
        print(f'\ndetector, IoU >= 0.5, instances with visib_fract >= {args.min_visib} '
              '(v30: >= 0.3)')
        print(format_detection_report(detection))
    if args.json is not None:
        records = write_instances(args.json, scores)
        write_json_atomic(args.json, report)
        print(f'report written to {args.json} (instances: {records})')
    if args.plots is not None:
        write_plots(args.plots, scores, report['objects'], report.get('sweep'),
                    report['confidence'])
        print(f'plots written to {args.plots}')
    return 0


def write_plots(folder: Path, scores: Mapping[str, Sequence[InstanceScore]],
                per_object: Mapping[str, Mapping[str, Any]],
                sweep: Sequence[Mapping[str, Any]] | None = None,
                confidence: Sequence[Mapping[str, float]] | None = None) -> None:
    """Write the evaluation charts into ``folder`` (matplotlib is imported only here)."""
    from bbpose_ros.core.eval import plots
    plots.recall_curves(scores, folder / 'recall_curves.png')
    plots.object_bars(per_object, folder / 'objects.png')
    plots.errors_by_visibility(scores, folder / 'visibility.png')
    if confidence:
        plots.confidence_sweep(confidence, folder / 'confidence.png')
    if sweep:
        plots.refinement_basin(sweep, folder / 'refinement_basin.png')
