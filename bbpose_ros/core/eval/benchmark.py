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
Speed of the pose pipeline stage by stage on real frames, and process readings (no ROS).

``benchmark_frames`` times each frame as the node handles it, in milliseconds:

* ``image_conversion``: the message buffer -> (H, W, 3) RGB array;
* ``image_decode``: given ``to_compressed`` and ``from_compressed``, the frame as a
  compressed camera sends it (image_transport's compressed: a JPEG) -> (H, W, 3) RGB
  array, what the node's worker pays per frame with ``image_transport: compressed``; timed
  in the detector mode apart from the frame (not in its total: the default transport, raw,
  does not decode);
* ``detector``: the 2D detector on the whole frame;
* ``correspondences``: the dense net on all objects' crops (one batch), when the pipeline
  runs it (``PipelineOptions.runs_dense``);
* ``qnet``: crop + Q-Net for all objects of the frame (one batch);
* ``hypothesis_selection``: choosing among a multi-hypothesis Q-Net's rotations with the
  Bounding Box Equation (``hypotheses``; absent when the pipeline does not), and
  ``qnet_and_selection`` the two together (the Q-Net budget counts ``qnet`` only);
* ``bbox_equation``: the Bounding Box Equation for all of them (one batched call), and
  ``bbox_equation_per_object`` the same divided by the number of objects;
* ``refinement``: region-based refinement of all poses of the frame (when the pipeline
  refines), and ``refinement_per_object`` the same divided by the number of poses;
* ``messages``: building the frame's output messages.

Buffers and messages are made by callables, so the ROS layer times the node's own code while
this module stays ROS-free. Each frame is timed in two modes: ``detector`` (the detector's
own detections, what the node does) and ``all_objects`` (the detector still runs, but Q-Net,
the equation and the messages get the ground-truth amodal box of every annotated object of
the frame: the worst case of the speed budget). With a refining pipeline a third mode,
``tracking``, times what a tracked frame costs: the frame's refined poses of the
``all_objects`` mode refined again as tracks (``tracking_per_object``), without detector or
Q-Net, plus image conversion and messages.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
import os
from pathlib import Path
import platform
import resource
import time
from typing import Any, TYPE_CHECKING

import numpy as np

from bbpose_ros.core.eval.evaluation import ground_truth_detections
from bbpose_ros.core.pipeline.latency import latency_stats, stage_stats
from bbpose_ros.core.util.errors import InputError

if TYPE_CHECKING:
    from bbpose_ros.core.data.bop import BopFrame
    from bbpose_ros.core.pipeline.pose_pipeline import PosePipeline
    from bbpose_ros.core.pipeline.poses import PoseEstimate

STAGES = ('image_conversion', 'image_decode', 'detector', 'correspondences', 'qnet',
          'hypothesis_selection', 'qnet_and_selection', 'bbox_equation',
          'bbox_equation_per_object', 'refinement', 'refinement_per_object', 'tracking',
          'tracking_per_object', 'messages')
MODES = ('detector', 'all_objects')

# The speed budgets (ms, on 2 CPU cores): (mode, stage, statistic, limit). They leave the
# learned stages room for accuracy within one frame period at 30 Hz.
FRAME_BUDGETS = {
    'bbox_equation_per_object': ('all_objects', 'bbox_equation_per_object', 'median_ms', 0.1),
    'qnet_all_objects': ('all_objects', 'qnet', 'median_ms', 8.0),
    'detector': ('detector', 'detector', 'median_ms', 20.0),
    'frame_all_objects_p95': ('all_objects', 'total', 'p95_ms', 33.0),
}
# With refinement the frame may take two periods at 30 Hz; a tracked frame one.
REFINED_FRAME_BUDGETS = {
    'bbox_equation_per_object': FRAME_BUDGETS['bbox_equation_per_object'],
    'qnet_all_objects': FRAME_BUDGETS['qnet_all_objects'],
    'detector': FRAME_BUDGETS['detector'],
    'refinement_per_object': ('all_objects', 'refinement_per_object', 'median_ms', 15.0),
    'frame_all_objects_p95': ('all_objects', 'total', 'p95_ms', 66.0),
    'tracking_per_object': ('tracking', 'tracking_per_object', 'median_ms', 3.0),
    'frame_tracking_p95': ('tracking', 'total', 'p95_ms', 33.0),
}
GRAPH_LATENCY_P95_MS = 40.0
GRAPH_RSS_GROWTH_PERCENT = 5.0
# A soak (a graph run of two minutes or more) also bounds how much the per-minute answer
# latency p95 may drift from the first full minute to the last.
SOAK_LATENCY_P95_DRIFT_PERCENT = 10.0
# Seconds into a graph run after which the node's RSS counts as settled (see rss_settle_s):
# a soak settles after its first minute, a shorter run after RSS_SETTLE_S.
RSS_SETTLE_S = 10.0
SOAK_SETTLE_S = 60.0
_CLOCK_TICKS_PER_S = os.sysconf('SC_CLK_TCK')     # unit of /proc/<pid>/stat CPU times


def cpu_name() -> str:
    """Name the CPU as /proc/cpuinfo's 'model name' does (Linux), else as platform does."""
    try:
        for line in Path('/proc/cpuinfo').read_text().splitlines():
            if line.startswith('model name'):
                return line.split(':', 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or 'unknown'


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far, in MiB."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0   # Linux: KiB


@dataclass(frozen=True)
class ProcessSample:
    """A process's CPU time used so far (user + system, s) and RSS (MiB) at time_s (monotonic)."""

    time_s: float
    cpu_s: float
    rss_mb: float


def sample_process(pid: int) -> ProcessSample:
    """Read the CPU time and resident memory of process ``pid`` from /proc (Linux)."""
    try:
        stat = Path(f'/proc/{pid}/stat').read_text()
        status = Path(f'/proc/{pid}/status').read_text()
    except OSError as err:
        raise InputError(f'process {pid} is gone ({err})') from err
    fields = stat[stat.rindex(')') + 2:].split()     # from field 3 (state) on
    ticks = int(fields[11]) + int(fields[12])        # fields 14 and 15: utime, stime
    rss_kb = next(int(line.split()[1]) for line in status.splitlines()
                  if line.startswith('VmRSS:'))
    return ProcessSample(time.monotonic(), ticks / _CLOCK_TICKS_PER_S, rss_kb / 1024.0)


def cpu_percent(start: ProcessSample, end: ProcessSample) -> float:
    """CPU use between two ProcessSamples, in % of one core (up to 100 x cores)."""
    return 100.0 * (end.cpu_s - start.cpu_s) / max(end.time_s - start.time_s, 1e-9)


def benchmark_frames(frames: Sequence[BopFrame], pipeline: PosePipeline,
                     to_buffer: Callable[[np.ndarray], Any],
                     from_buffer: Callable[[Any], np.ndarray],
                     build_messages: Callable[[list[PoseEstimate]], Any],
                     warmup: int = 10, tracking_iterations: int = 3,
                     to_compressed: Callable[[np.ndarray], Any] | None = None,
                     from_compressed: Callable[[Any], np.ndarray] | None = None
                     ) -> dict[str, Any]:
    """
    Time the pipeline on each frame in both MODES and return the report.

    Args:
        frames: BopFrame list; images are read one at a time, untimed.
        pipeline: a PosePipeline with a detector and a rotation estimator.
        to_buffer: (H, W, 3) uint8 RGB -> the message the node would receive (untimed).
        from_buffer: that message -> (H, W, 3) uint8 RGB (the node's image conversion).
        build_messages: list of PoseEstimate -> the frame's output messages.
        warmup: untimed frames first (the first frames again), in both modes.
        tracking_iterations: correspondence iterations of a tracking refinement.
        to_compressed: (H, W, 3) uint8 RGB -> the frame compressed (untimed); with
            ``from_compressed`` (compressed -> RGB, timed) the stage ``image_decode``.

    Returns:
        {'stages': {stage: latency_stats}, 'total', 'fps', 'objects_per_frame'} of the
        detector mode, its 'all_objects' and (refining pipelines) 'tracking' counterparts,
        'peak_rss_mb', 'frames', 'cpu' (its name), 'cpu_count' and 'budgets'
        ({name: {'value', 'limit', 'met'}}).

    """
    if not frames:
        raise InputError('no frames to benchmark')
    refining = pipeline.refiner is not None
    timings = {mode: [] for mode in MODES + (('tracking',) if refining else ())}
    for index in range(-warmup, len(frames)):
        frame = frames[index % len(frames)]
        image = frame.load_image()
        buffer = to_buffer(image)
        truth = ground_truth_detections(
            [i for i in frame.instances if np.all(np.isfinite(i.box_uv))])
        for mode, oracle in zip(MODES, (None, truth)):
            times, poses = _time_frame(pipeline, frame.camera, buffer, from_buffer,
                                       build_messages, oracle)
            if index >= 0:
                timings[mode].append(times)
        if to_compressed is not None and from_compressed is not None:
            decode_ms = _time_decode(from_compressed, to_compressed(image))
            if index >= 0:
                timings['detector'][-1]['image_decode'] = decode_ms
        if refining and index >= 0:
            timings['tracking'].append(_time_tracking(pipeline, frame.camera, buffer,
                                                      from_buffer, build_messages, poses,
                                                      tracking_iterations))
    report = _summary(timings['detector'])
    report['all_objects'] = _summary(timings['all_objects'])
    if refining:
        report['tracking'] = _summary(timings['tracking'])
    report.update(peak_rss_mb=peak_rss_mb(), frames=len(frames), cpu=cpu_name(),
                  cpu_count=os.cpu_count())
    budgets = REFINED_FRAME_BUDGETS if refining else FRAME_BUDGETS
    report['budgets'] = {name: budget(_frame_statistic(report, *where[:3]), where[3])
                         for name, where in budgets.items()}
    return report


def rss_settle_s(duration_s: float) -> float:
    """Seconds into a graph run of ``duration_s`` after which the node's RSS counts as settled."""
    return SOAK_SETTLE_S if duration_s >= 2 * SOAK_SETTLE_S else RSS_SETTLE_S


def summarize_graph(latencies: Sequence[Mapping[str, float]], published: int,
                    node_start: ProcessSample, node_end: ProcessSample,
                    node_counts: Mapping[str, int],
                    rss_trace: Sequence[tuple[float, float]] = (),
                    rate_hz: float | None = None,
                    settle_s: float = RSS_SETTLE_S) -> dict[str, Any]:
    """
    Make the report of a fixed-rate run through the ROS graph.

    Args:
        latencies: per published frame, in publication order, {'end_to_end': ms to its last
            PoseStamped (frames with poses), 'answer': ms to its MarkerArray (answered
            frames)}.
        published: number of frames published.
        node_start, node_end: ProcessSamples of the node at the first and last publication.
        node_counts: {counter: frames} the node counted during the run.
        rss_trace: [(seconds since the first publication, node RSS in MB)].
        rate_hz: the publication rate; frame k went out k / rate_hz s into the run. Given,
            the report has per-minute figures.
        settle_s: seconds into the run after which the RSS counts as settled
            (``rss_settle_s``).

    Returns:
        {'latency', 'answer_latency': latency_stats, 'latency_drift_ms' (median answer
        latency of the last third of the frames minus the first third's), 'frames':
        {'published', 'answered', 'dropped', 'with_poses'}, 'node': {'cpu_percent',
        'rss_start_mb', 'rss_end_mb', 'rss_growth_percent', 'rss_settled_at_s',
        'rss_settled_mb' (the first sample settle_s into the run; None in a shorter run),
        'rss_growth_after_settle_percent', 'rss_trace_mb', 'counts'}, 'per_minute' (with
        rate_hz: per minute of publication {'minute', 'published', 'answered',
        'answer_latency_median_ms', 'answer_latency_p95_ms', 'rss_mb' (the last sample of
        the minute)}), 'latency_p95_drift_percent' (the answer p95 of the last full minute
        against the first's, in %; None with fewer than two full minutes), 'cpu' (its
        name), 'cpu_count', 'budgets'}.
        The budgets are on the answer p95, the frames dropped and 'rss_growth_percent',
        and, where known, on the growth after settling and the p95 drift; the settled
        figures tell a one-off step in the first seconds from a steady climb.

    """
    answers = [frame['answer'] for frame in latencies if 'answer' in frame]
    third = len(answers) // 3
    growth = 100.0 * (node_end.rss_mb - node_start.rss_mb) / node_start.rss_mb
    settled = next((mb for seconds, mb in rss_trace if seconds >= settle_s), None)
    report = {
        'latency': latency_stats([f['end_to_end'] for f in latencies if 'end_to_end' in f]),
        'answer_latency': latency_stats(answers),
        'latency_drift_ms': float(np.median(answers[-third:]) - np.median(answers[:third]))
        if third else None,
        'frames': {'published': published, 'answered': len(answers),
                   'dropped': published - len(answers),
                   'with_poses': sum('end_to_end' in f for f in latencies)},
        'node': {'cpu_percent': cpu_percent(node_start, node_end),
                 'rss_start_mb': node_start.rss_mb, 'rss_end_mb': node_end.rss_mb,
                 'rss_growth_percent': growth, 'rss_settled_at_s': settle_s,
                 'rss_settled_mb': settled,
                 'rss_growth_after_settle_percent':
                     None if settled is None else 100.0 * (node_end.rss_mb - settled) / settled,
                 'rss_trace_mb': [[round(s, 2), round(mb, 1)] for s, mb in rss_trace],
                 'counts': dict(node_counts)},
        'cpu': cpu_name(), 'cpu_count': os.cpu_count()}
    report['per_minute'], report['latency_p95_drift_percent'] = (
        _per_minute(latencies, rss_trace, rate_hz) if rate_hz else ([], None))
    report['budgets'] = {
        'answer_latency_p95': budget(report['answer_latency']['p95_ms'],
                                     GRAPH_LATENCY_P95_MS),
        'frames_dropped': budget(report['frames']['dropped'], 0),
        'rss_growth_percent': budget(growth, GRAPH_RSS_GROWTH_PERCENT)}
    soak = {'rss_growth_after_settle_percent': (report['node']['rss_growth_after_settle_percent'],
                                                GRAPH_RSS_GROWTH_PERCENT),
            'latency_p95_drift_percent': (report['latency_p95_drift_percent'],
                                          SOAK_LATENCY_P95_DRIFT_PERCENT)}
    report['budgets'].update((name, budget(value, limit))
                             for name, (value, limit) in soak.items() if value is not None)
    return report


def _per_minute(latencies, rss_trace, rate_hz):
    """Per-minute figures of a fixed-rate run and the p95 drift of its full minutes."""
    per_minute_frames = int(round(60.0 * rate_hz))
    minutes, full = [], []
    for start in range(0, len(latencies), per_minute_frames):
        frames = latencies[start:start + per_minute_frames]
        answers = latency_stats([f['answer'] for f in frames if 'answer' in f])
        minute = len(minutes) + 1
        rss = [mb for seconds, mb in rss_trace if minute - 1 <= seconds / 60.0 < minute]
        minutes.append({'minute': minute, 'published': len(frames),
                        'answered': sum('answer' in f for f in frames),
                        'answer_latency_median_ms': answers['median_ms'],
                        'answer_latency_p95_ms': answers['p95_ms'],
                        'rss_mb': rss[-1] if rss else None})
        if len(frames) == per_minute_frames and answers['p95_ms'] is not None:
            full.append(answers['p95_ms'])
    drift = 100.0 * (full[-1] - full[0]) / full[0] if len(full) >= 2 else None
    return minutes, drift


def budget(value: float | None, limit: float) -> dict[str, Any]:
    """Return {'value', 'limit', 'met'}: met when the value is known and at most the limit."""
    return {'value': value, 'limit': limit, 'met': value is not None and value <= limit}


def _frame_statistic(report, mode, stage, statistic):
    summary = report if mode == 'detector' else report.get(mode, {'stages': {}, 'total': {}})
    stats = summary['total'] if stage == 'total' else summary['stages'].get(stage, {})
    return stats.get(statistic)


def _summary(per_frame):
    """Return the stage statistics, total, fps and objects per frame of timed frames."""
    totals = [times.pop('total') for times in per_frame]
    counts = [times.pop('objects') for times in per_frame]
    stages = stage_stats(per_frame)
    return {'stages': {stage: stages[stage] for stage in STAGES if stage in stages},
            'total': latency_stats(totals), 'fps': 1e3 * len(totals) / sum(totals),
            'objects_per_frame': float(np.mean(counts))}


def _time_frame(pipeline, camera, buffer, from_buffer, build_messages, oracle):
    """
    Time one frame: ({stage: ms, 'total': ms, 'objects': count}, its poses).

    ``oracle`` replaces the detections.
    """
    start = time.perf_counter()
    image = from_buffer(buffer)
    converted = time.perf_counter()
    found = pipeline.detector(image)
    detected = time.perf_counter()
    result = pipeline.estimate(image, camera, found if oracle is None else oracle)
    estimated = time.perf_counter()
    build_messages(result.poses)
    end = time.perf_counter()
    times = {'image_conversion': _ms(start, converted), 'detector': _ms(converted, detected),
             'messages': _ms(estimated, end), 'total': _ms(start, end),
             'objects': len(result.poses)}
    if result.poses:
        if 'correspondences' in result.timings_ms:
            times['correspondences'] = result.timings_ms['correspondences']
        times['qnet'] = result.timings_ms['rotation']
        if 'hypothesis_selection' in result.timings_ms:
            times['hypothesis_selection'] = result.timings_ms['hypothesis_selection']
            times['qnet_and_selection'] = times['qnet'] + times['hypothesis_selection']
        times['bbox_equation'] = result.timings_ms['translation']
        times['bbox_equation_per_object'] = times['bbox_equation'] / len(result.poses)
        if 'refinement' in result.timings_ms:
            times['refinement'] = result.timings_ms['refinement']
            times['refinement_per_object'] = times['refinement'] / len(result.poses)
    return times, result.poses


def _time_decode(from_compressed, compressed):
    """Time decoding one compressed frame, in ms."""
    start = time.perf_counter()
    from_compressed(compressed)
    return _ms(start, time.perf_counter())


def _time_tracking(pipeline, camera, buffer, from_buffer, build_messages, poses, iterations):
    """Time a tracked frame: the given poses refined again as tracks (see the module)."""
    start = time.perf_counter()
    image = from_buffer(buffer)
    converted = time.perf_counter()
    results = pipeline.refiner.refine_tracks(
        image, camera, [p.object_name for p in poses], [p.rotation for p in poses],
        [p.translation for p in poses], [None] * len(poses), iterations)
    tracked = time.perf_counter()
    build_messages([replace(p, rotation=r.rotation, translation=r.translation)
                    for p, r in zip(poses, results)])
    end = time.perf_counter()
    times = {'image_conversion': _ms(start, converted), 'messages': _ms(tracked, end),
             'total': _ms(start, end), 'objects': len(poses)}
    if poses:
        times['tracking'] = _ms(converted, tracked)
        times['tracking_per_object'] = times['tracking'] / len(poses)
    return times


def _ms(start_s, end_s):
    return (end_s - start_s) * 1e3
