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
``bbpose bench``: the speed of the pipeline stage by stage, or through the ROS graph.

Both modes take the node's parameters (``--params``, default config/bbpose.yaml, and
``--param``); ``--dataset``, ``--objects`` and the pipeline settings' options (generated
from ``options.SETTINGS``, e.g. ``--inference-threads``, ``--score-threshold``) become
overrides of the parameters of the same names, so the stage benchmark builds the very
pipeline the node would, and ``--graph`` starts the node with them.
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping, Sequence
import os
from pathlib import Path
from typing import Any

from std_msgs.msg import Header

from bbpose_ros.bags import topics
from bbpose_ros.cli.common import add_dataset_argument, add_objects_argument
from bbpose_ros.cli.graph.graph_bench import camera_messages, camera_transforms, run_graph
from bbpose_ros.cli.graph.replay import DEFAULT_PARAMS
from bbpose_ros.cli.settings_options import (add_settings_options, PIPELINE_TITLE,
                                             settings_given)
from bbpose_ros.core.data.bop import BopDataset, BopFrame
from bbpose_ros.core.data.compressed_image import decode_compressed, DEFAULT_JPEG_QUALITY
from bbpose_ros.core.data.compressed_image import encode_compressed
from bbpose_ros.core.eval.benchmark import benchmark_frames, rss_settle_s, STAGES
from bbpose_ros.core.eval.benchmark import summarize_graph
from bbpose_ros.core.eval.recorded_poses import latencies_ms
from bbpose_ros.core.inference.options import PipelineOptions, SETTINGS
from bbpose_ros.core.pipeline.tracking import PoseTracker
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.core.util.files import write_json_atomic
from bbpose_ros.ros import conversions
from bbpose_ros.ros.node_pipeline import build_node_pipeline
from bbpose_ros.ros.params import read_config
from bbpose_ros.ros.params_file import read_params_file


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register the ``bench`` subcommand."""
    parser = subparsers.add_parser(
        'bench', help='time the pipeline stages, or the node through the ROS graph',
        description='Without --graph: run the pipeline on BOP frames after a warm-up and '
                    'report per stage (image conversion, detector, crop + Q-Net, Bounding Box '
                    'Equation, refinement, message building) and in total the median, p95 and '
                    'max in ms, fps, peak RSS, the inference threads and the networks run, '
                    'and apart from the total image_decode (a JPEG of the frame, as '
                    'image_transport compressed sends it, decoded as the node does); '
                    "once with the detector's detections and "
                    'once ("all_objects") with the ground-truth box of every object of the '
                    'frame. With --graph: start '
                    'bbpose_node, publish the frames at --rate for --duration seconds over DDS '
                    '(shipped Fast DDS profile) and report the publish -> answer latency, '
                    'frames answered / dropped, node CPU and RSS.')
    add_dataset_argument(parser)
    add_objects_argument(parser)
    parser.add_argument('--frames', type=int, default=None,
                        help='use the first N frames of the dataset (default: all)')
    parser.add_argument('--warmup', type=int, default=10,
                        help='untimed frames before timing (default %(default)s)')
    parser.add_argument('--graph', action='store_true',
                        help='measure through the ROS graph with a running node')
    parser.add_argument('--rate', type=float, default=30.0,
                        help='--graph: frames per second (default %(default)s)')
    parser.add_argument('--duration', type=float, default=60.0,
                        help='--graph: seconds of publishing (default %(default)s); from 120 s '
                             'on, a soak: per-minute latency and RSS, RSS growth after the '
                             'first minute, p95 drift')
    parser.add_argument('--params', type=Path, default=DEFAULT_PARAMS,
                        help='parameters file of the node (default %(default)s)')
    parser.add_argument('--param', action='append', default=[], metavar='NAME:=VALUE',
                        help='override one node parameter (repeatable)')
    parser.add_argument('--json', type=Path, default=None, help='write the report here')
    # Unset, each takes the parameters file's value.
    add_settings_options(parser, PipelineOptions, PIPELINE_TITLE)
    parser.set_defaults(func=run)


def node_overrides(args: argparse.Namespace) -> list[str]:
    """Make the ``name:=value`` parameter overrides of the options, then ``--param``."""
    overrides = [f'dataset_dir:={args.dataset.resolve()}']
    if args.objects:
        overrides.append(f'objects:=[{",".join(args.objects)}]')
    overrides += [f'{name}:={value!r}' if isinstance(value, str) else f'{name}:={value}'
                  for name, value in settings_given(args, SETTINGS).items()]
    return overrides + list(args.param)


def bench_frames(frames: Sequence[BopFrame], values: dict[str, Any],
                 warmup: int) -> dict[str, Any]:
    """Time the stages on ``frames`` with the pipeline the node builds from ``values``."""
    config = read_config(values)
    built = build_node_pipeline(config)
    pipeline = built.pipeline
    if isinstance(pipeline, PoseTracker):     # the stages are timed on the pipeline itself
        pipeline = pipeline.pipeline
    header = Header(frame_id=topics.DEFAULT_FRAME_ID)
    report = benchmark_frames(
        frames, pipeline, lambda image: conversions.rgb_to_image(header, image),
        conversions.image_to_rgb,
        lambda poses: conversions.frame_messages(header, poses, built.markers),
        warmup=warmup,
        to_compressed=lambda image: encode_compressed(image, 'jpeg', DEFAULT_JPEG_QUALITY),
        from_compressed=lambda compressed: decode_compressed(
            *compressed, values['max_image_pixels']))
    options = config.options
    report.update(inference_backend=options.inference_backend,
                  detector_network=pipeline.detector.precision,
                  qnet_network=getattr(pipeline.rotation_estimator, 'precision', None),
                  inference_threads=options.inference_threads or os.cpu_count(),
                  refine=options.refine, refine_hypotheses=options.refine_hypotheses,
                  image_decode={'codec': 'jpeg', 'jpeg_quality': DEFAULT_JPEG_QUALITY})
    return report


def bench_graph(args: argparse.Namespace, frames: Sequence[BopFrame],
                values: dict[str, Any], overrides: Sequence[str]) -> dict[str, Any]:
    """Publish ``frames`` at ``args.rate`` into a node started with ``overrides``."""
    if args.rate <= 0 or args.duration <= 0:
        raise InputError('--rate and --duration must be positive')
    graph = run_graph(camera_messages(frames), list(values['objects']), args.params, overrides,
                      args.rate, args.duration, camera_transforms(frames))
    report = summarize_graph(latencies_ms(graph.recording), len(graph.recording.published_s),
                             graph.node_start, graph.node_end, graph.node_counts,
                             graph.node_rss_trace, rate_hz=args.rate,
                             settle_s=rss_settle_s(args.duration))
    report.update(rate_hz=args.rate, duration_s=args.duration,
                  node_timings_ms=graph.recording.timings_ms)
    report['node'].update(stop_s=graph.stop_s, exit_code=graph.exit_code)
    return report


def format_frames(report: Mapping[str, Any]) -> str:
    """Make the stage table of a stage benchmark report."""
    modes = [report, report['all_objects']]
    if 'tracking' in report:
        modes.append(report['tracking'])
    lines = [f'{"stage (ms)":26s}{"median":>9s}{"p95":>9s}{"max":>9s}'
             f'{"all: median":>13s}{"p95":>9s}{"max":>9s}'
             + (f'{"tracked: median":>17s}{"p95":>9s}{"max":>9s}' if len(modes) > 2 else '')]
    for stage in STAGES + ('total',):
        cells = [mode['total'] if stage == 'total' else mode['stages'].get(stage)
                 for mode in modes]
        row = ''.join(_cells(c, first=w) for c, w in zip(cells, (9, 13, 17)))
        lines.append(f'{stage:26s}{row}')
    lines.append(f'fps {report["fps"]:.1f} (all objects {report["all_objects"]["fps"]:.1f}); '
                 f'objects per frame {report["objects_per_frame"]:.2f} (all objects '
                 f'{report["all_objects"]["objects_per_frame"]:.2f}); peak RSS '
                 f'{report["peak_rss_mb"]:.0f} MB; {report["inference_backend"]} with '
                 f'{report["inference_threads"]} threads, detector '
                 f'{report["detector_network"]}, Q-Net {report["qnet_network"]}')
    return '\n'.join(lines + _format_budgets(report['budgets']))


def format_graph(report: Mapping[str, Any]) -> str:
    """Make the summary lines of a graph benchmark report."""
    frames, node = report['frames'], report['node']
    lines = [f'{"latency (ms)":26s}{"median":>9s}{"p95":>9s}{"max":>9s}',
             f'{"publish -> last pose":26s}{_cells(report["latency"])}',
             f'{"publish -> markers":26s}{_cells(report["answer_latency"])}',
             f'frames: {frames["published"]} published, {frames["answered"]} answered, '
             f'{frames["dropped"]} dropped, {frames["with_poses"]} with poses; node counted '
             f'{node["counts"]}',
             f'node: CPU {node["cpu_percent"]:.0f} %, RSS {node["rss_start_mb"]:.0f} -> '
             f'{node["rss_end_mb"]:.0f} MB ({node["rss_growth_percent"]:+.1f} %)'
             + ('' if node['rss_settled_mb'] is None else
                f'; from {node["rss_settled_at_s"]:.0f} s on {node["rss_settled_mb"]:.0f} -> '
                f'{node["rss_end_mb"]:.0f} MB ({node["rss_growth_after_settle_percent"]:+.1f} %)'),
             f'node stop (SIGINT -> exit): {node["stop_s"]:.2f} s, exit code {node["exit_code"]}']
    if len(report['per_minute']) > 1:
        lines.append(f'{"minute":>6s}{"published":>11s}{"answered":>10s}{"median ms":>11s}'
                     f'{"p95 ms":>9s}{"RSS MB":>9s}')
        lines += [f'{m["minute"]:>6d}{m["published"]:>11d}{m["answered"]:>10d}'
                  f'{_number(m["answer_latency_median_ms"], 11, 2)}'
                  f'{_number(m["answer_latency_p95_ms"], 9, 2)}{_number(m["rss_mb"], 9, 1)}'
                  for m in report['per_minute']]
    return '\n'.join(lines + _format_budgets(report['budgets']))


def run(args: argparse.Namespace) -> int:
    """Run the chosen benchmark, print its summary and write the JSON; returns 0."""
    overrides = node_overrides(args)
    values = read_params_file(args.params, overrides)
    frames = BopDataset(args.dataset).frames()[:args.frames]
    if not frames:
        raise InputError(f'no frames in {args.dataset}')
    if args.graph:
        report = bench_graph(args, frames, values, overrides)
        print(format_graph(report))
    else:
        report = bench_frames(frames, values, args.warmup)
        print(format_frames(report))
    report['config'] = {'dataset': str(args.dataset), 'params': str(args.params),
                        'overrides': overrides, 'frames': len(frames), 'graph': args.graph}
    if args.json is not None:
        write_json_atomic(args.json, report)
        print(f'report written to {args.json}')
    return 0


def _number(value, width, decimals):
    return f'{"-":>{width}s}' if value is None else f'{value:>{width}.{decimals}f}'


def _cells(stats, first=9):
    if not stats or stats['median_ms'] is None:
        return f'{"-":>{first}s}{"-":>9s}{"-":>9s}'
    return (f'{stats["median_ms"]:>{first}.3f}{stats["p95_ms"]:>9.3f}'
            f'{stats["max_ms"]:>9.3f}')


def _format_budgets(budgets):
    lines = []
    for name, entry in budgets.items():
        value = '-' if entry['value'] is None else f'{entry["value"]:.3f}'
        verdict = 'met' if entry['met'] else 'MISSED'
        lines.append(f'budget {name}: {value} (limit {entry["limit"]}) {verdict}')
    return lines
