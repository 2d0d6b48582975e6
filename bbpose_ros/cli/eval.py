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

import argparse
from pathlib import Path

from bbpose_ros.cli.common import (add_dataset_argument, add_frames_argument,
                                   add_objects_argument, float_pair)
from bbpose_ros.core.data.bop import BopDataset
from bbpose_ros.core.errors import InputError
from bbpose_ros.core.eval.detection import format_detection_report, score_detections
from bbpose_ros.core.eval.evaluation import format_report, make_report, score_frames
from bbpose_ros.core.files import write_json_atomic
from bbpose_ros.core.inference.options import (DENSE_MASKS, DENSE_TRANSLATIONS,
                                               PipelineOptions, POSE_SOURCES, PRECISIONS)
from bbpose_ros.core.pipeline.pose_pipeline import PosePipeline


def add_parser(subparsers):
    """Register the ``eval`` subcommand."""
    parser = subparsers.add_parser(
        'eval', help='evaluate the pipeline on BOP frames (table + JSON)',
        description='Run the pipeline on the frames of a BOP dataset and score it: ADD(-S), '
                    '5 cm / 5 deg, 2D projection, rotation and translation errors per object. '
                    '--boxes gt and --rotation gt replace the learned stages by the ground '
                    'truth, to isolate the Bounding Box Equation. With --boxes detector the '
                    'report also scores the detector (recall and AP at IoU 0.5).')
    add_dataset_argument(parser)
    parser.add_argument('--boxes', choices=('gt', 'detector'), default='detector',
                        help='2D boxes from the ground truth (amodal bbox_obj) or the detector')
    parser.add_argument('--rotation', choices=('gt', 'qnet'), default='qnet',
                        help='rotations from the ground truth or from Q-Net')
    parser.add_argument('--detector-weights', type=Path, default=None,
                        help='detector weight file (default: the shipped one)')
    parser.add_argument('--qnet-weights', type=Path, default=None,
                        help='Q-Net weight file (default: the shipped one)')
    add_pipeline_arguments(parser)
    parser.add_argument('--perturb-gt', type=float_pair, action='append', default=None,
                        metavar='DEG,MM',
                        help='with --boxes gt --rotation gt: start each pose from the ground '
                             'truth turned DEG degrees about a random axis and moved MM '
                             'millimetres in a random direction, then refine it (the '
                             "refiner's basin). Repeat it for a sweep: the report is the "
                             "first level's, with every level's means under 'sweep', and "
                             '--plots draws refinement_basin.png')
    parser.add_argument('--seed', type=int, default=0,
                        help='seed of the --perturb-gt perturbations (default %(default)s)')
    add_objects_argument(parser)
    add_frames_argument(parser)
    parser.add_argument('--min-visib', type=float, default=0.1,
                        help='count instances at least this visible (default %(default)s)')
    parser.add_argument('--json', type=Path, default=None, help='write the report here')
    parser.add_argument('--plots', type=Path, default=None,
                        help='write charts into this folder: recall curves, per-object '
                             'recalls, errors by visible fraction, what a minimum confidence '
                             'keeps')
    parser.set_defaults(func=run)


def add_pipeline_arguments(parser):
    """Add the PipelineOptions that an evaluation varies, with their defaults."""
    defaults = PipelineOptions()
    parser.add_argument('--box-consistency-weight', type=float,
                        default=defaults.box_consistency_weight,
                        help='how much the Bounding Box Equation misfit counts in choosing '
                             'among Q-Net hypotheses; 0: the best-scored one '
                             '(default %(default)s)')
    parser.add_argument('--mask-consistency-weight', type=float,
                        default=defaults.mask_consistency_weight,
                        help="how much each Q-Net hypothesis' silhouette agreement (soft IoU) "
                             "with the dense net's amodal mask counts in ranking them; 0: "
                             'none (default %(default)s)')
    parser.add_argument('--refine', action=argparse.BooleanOptionalAction,
                        default=defaults.refine,
                        help='refine each pose by aligning the silhouette with the image '
                             '(default: %(default)s)')
    parser.add_argument('--refine-min-score', type=float, default=defaults.refine_min_score,
                        help='drop refined poses scored below this, 0..1 (default %(default)s)')
    parser.add_argument('--refine-hypotheses', type=int, default=defaults.refine_hypotheses,
                        help="refine each detection's K best-ranked rotation hypotheses and "
                             'keep the best-scored (default %(default)s)')
    parser.add_argument('--refine-prior-deg', type=float, default=defaults.refine_prior_deg,
                        help="standard deviation of a prior around each start's rotation, "
                             'degrees: the refinement moves a start less the smaller it is; '
                             '0: none (default %(default)s)')
    parser.add_argument('--refine-prior-mm', type=float, default=defaults.refine_prior_mm,
                        help="the same for the start's translation, millimetres "
                             '(default %(default)s)')
    parser.add_argument('--refine-occlusions', action=argparse.BooleanOptionalAction,
                        default=defaults.refine_occlusions,
                        help="let the poses of a frame hide each other's contour where one "
                             'is nearer the camera (default: %(default)s)')
    parser.add_argument('--refine-mask-choice-weight', type=float,
                        default=defaults.refine_mask_choice_weight,
                        help="where the dense net runs, how much each refined candidate's "
                             'silhouette agreement with its amodal mask counts beside the '
                             'refinement score in choosing; 0: the score alone '
                             '(default %(default)s)')
    parser.add_argument('--pose-source', choices=POSE_SOURCES, default=defaults.pose_source,
                        help='candidate poses from Q-Net + the Bounding Box Equation (qnet, '
                             'the paper), PnP over the dense correspondences (dense), or both '
                             '(default %(default)s)')
    parser.add_argument('--dense-translation', choices=DENSE_TRANSLATIONS,
                        default=defaults.dense_translation,
                        help="dense poses' translation: PnP's, the Bounding Box Equation's "
                             "from PnP's rotation, or both candidates (default %(default)s)")
    parser.add_argument('--dense-mask', choices=DENSE_MASKS, default=defaults.dense_mask,
                        help="the refiner's foreground model: the dense net's amodal or "
                             'visible mask, or none (colours) (default %(default)s)')
    parser.add_argument('--dense-weights', type=Path, default=None,
                        help='dense net weight file (default: the shipped one)')
    parser.add_argument('--inference-precision', choices=PRECISIONS, default=defaults.precision,
                        help='the detector and Q-Net: fp32, their int8 graphs, or auto (int8 '
                             'on a CPU with int8 dot products) (default %(default)s)')


def pipeline_options(args):
    """Return the PipelineOptions of ``add_pipeline_arguments``' options (InputError if bad)."""
    try:
        return PipelineOptions(box_consistency_weight=args.box_consistency_weight,
                               mask_consistency_weight=args.mask_consistency_weight,
                               refine=args.refine, refine_min_score=args.refine_min_score,
                               refine_hypotheses=args.refine_hypotheses,
                               refine_prior_deg=args.refine_prior_deg,
                               refine_prior_mm=args.refine_prior_mm,
                               refine_occlusions=args.refine_occlusions,
                               refine_mask_choice_weight=args.refine_mask_choice_weight,
                               pose_source=args.pose_source,
                               dense_translation=args.dense_translation,
                               dense_mask=args.dense_mask,
                               precision=args.inference_precision)
    except InputError as err:
        option, _, reason = str(err).partition(': ')
        raise InputError(f'--{option.replace("_", "-")}: {reason}') from err


def build_pipeline(models, args):
    """Build a pipeline with learned stages only where the ground truth does not replace them."""
    options = pipeline_options(args)
    if args.boxes == 'gt' and args.rotation == 'gt':
        refiner = correspondences = None
        if options.refine:
            from bbpose_ros.core.pipeline.refinement import load_pose_refiner
            refiner = load_pose_refiner(
                models, options.refiner_config, min_score=options.refine_min_score,
                mask_choice_weight=options.refine_mask_choice_weight)
        # The dense net runs for the refiner's foreground mask or its choice by the mask.
        if options.refine and (options.dense_mask != 'none' or (
                options.runs_dense and options.refine_mask_choice_weight > 0.0)):
            from bbpose_ros.core.pipeline.loader import load_correspondences
            correspondences = load_correspondences(models, options, args.dense_weights)
        return PosePipeline(models, refiner=refiner, correspondences=correspondences,
                            dense_poses=False, dense_mask=options.dense_mask)
    from bbpose_ros.core.pipeline.loader import load_pipeline
    return load_pipeline(models, options, args.detector_weights, args.qnet_weights,
                         dense_weights=args.dense_weights)


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


def run(args):
    """Evaluate, print the table(s) and write the JSON; returns the exit code."""
    dataset = BopDataset(args.dataset)
    models = dataset.load_models(args.objects)
    frames = dataset.frames()[:args.max_frames]
    levels = args.perturb_gt or [None]
    if args.perturb_gt is not None and (args.boxes != 'gt' or args.rotation != 'gt'):
        raise InputError('--perturb-gt needs --boxes gt --rotation gt')
    pipeline = build_pipeline(models, args)
    recorder = None
    if args.boxes == 'detector':
        recorder = pipeline.detector = RecordingDetector(pipeline.detector)
    sweep = []
    for level in levels:
        perturb = None if level is None else (level[0], level[1] / 1000.0)
        level_scores, timings = score_frames(
            frames, pipeline, boxes=args.boxes,
            rotation='gt' if args.rotation == 'gt' else 'estimator', min_visib=args.min_visib,
            perturb=perturb, seed=args.seed)
        level_report = make_report(level_scores, timings, len(frames))
        if level is not None:
            sweep.append({'deg': level[0], 'mm': level[1], 'mean': level_report['mean']})
        if len(sweep) <= 1:
            report, scores = level_report, level_scores
    if len(sweep) > 1:
        report['sweep'] = sweep
    detection = None
    if recorder is not None:
        pipeline.detector = recorder.detector
        detection = score_detections(frames, recorder.calls, list(models), args.min_visib)
        report['detection'] = {**detection['detection'], 'mean': detection['mean']}
    report['config'] = {'dataset': str(args.dataset), 'boxes': args.boxes,
                        'rotation': args.rotation, 'min_visib': args.min_visib,
                        'detector_weights': _weights_name(args.detector_weights),
                        'qnet_weights': _weights_name(args.qnet_weights),
                        'box_consistency_weight': args.box_consistency_weight,
                        'mask_consistency_weight': args.mask_consistency_weight,
                        'refine': args.refine, 'refine_min_score': args.refine_min_score,
                        'refine_hypotheses': args.refine_hypotheses,
                        'refine_prior_deg': args.refine_prior_deg,
                        'refine_prior_mm': args.refine_prior_mm,
                        'refine_occlusions': args.refine_occlusions,
                        'refine_mask_choice_weight': args.refine_mask_choice_weight,
                        'pose_source': args.pose_source,
                        'dense_translation': args.dense_translation,
                        'dense_mask': args.dense_mask,
                        'dense_weights': _weights_name(args.dense_weights),
                        'inference_precision': args.inference_precision,
                        'detector_network': getattr(pipeline.detector, 'precision', None),
                        'qnet_network': getattr(pipeline.rotation_estimator, 'precision',
                                                None),
                        'perturb_gt_deg_mm': args.perturb_gt, 'seed': args.seed}
    print(format_report(report))
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
        write_json_atomic(args.json, report)
        print(f'report written to {args.json}')
    if args.plots is not None:
        write_plots(args.plots, scores, report['objects'], report.get('sweep'),
                    report['confidence'])
        print(f'plots written to {args.plots}')
    return 0


def write_plots(folder, scores, per_object, sweep=None, confidence=None):
    """Write the evaluation charts into ``folder`` (matplotlib is imported only here)."""
    from bbpose_ros.core.eval import plots
    plots.recall_curves(scores, folder / 'recall_curves.png')
    plots.object_bars(per_object, folder / 'objects.png')
    plots.errors_by_visibility(scores, folder / 'visibility.png')
    if confidence:
        plots.confidence_sweep(confidence, folder / 'confidence.png')
    if sweep:
        plots.refinement_basin(sweep, folder / 'refinement_basin.png')
