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

"""Stream mode: the tracks answer every frame, the full pipeline runs beside them."""

from dataclasses import replace
import threading
import time

import numba
import numpy as np
import pytest
import torch

from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.inference.weights import save_weights
from bbpose_ros.core.nets.dense import DenseConfig, DenseNet
from bbpose_ros.core.nets.detector import CenterBoxNet, DetectorConfig
from bbpose_ros.core.nets.qnet import QNet, QNetConfig
from bbpose_ros.core.pipeline import stream_schedule
from bbpose_ros.core.pipeline.loader import load_pipeline, WeightFiles
from bbpose_ros.core.pipeline.pose_pipeline import PosePipeline
from bbpose_ros.core.pipeline.poses import Detection
from bbpose_ros.core.pipeline.refinement import PoseRefiner
from bbpose_ros.core.pipeline.tracking import PoseTracker, Track
from bbpose_ros.core.refine import kernel_launch
from bbpose_ros.core.refine.refiner import compile_kernels
from bbpose_ros.core.refine.viewpoint_cache import load_viewpoint_models
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.ros.diagnostics import stage_rates

pytestmark = pytest.mark.slow   # real frames refined in two threads
NAMES = ('ape', 'can', 'cat', 'driller', 'duck', 'eggbox', 'glue', 'holepuncher')
WAIT_S = 60.0


class GatedDetector:
    """The ground-truth boxes of a frame, returned once the gate opens; counts its runs."""

    def __init__(self, truths, delay_s=0.0):
        self.truths = truths
        self.delay_s = delay_s
        self.gate = threading.Event()
        self.calls = 0
        self.running = 0
        self.most_running = 0

    def __call__(self, image_rgb):
        self.calls += 1
        self.running += 1
        self.most_running = max(self.most_running, self.running)
        self.gate.wait(WAIT_S)
        time.sleep(self.delay_s)
        self.running -= 1
        return [Detection(i.object_name, 0.9, i.box_uv) for i in self.truths]


@pytest.fixture(scope='module')
def scene(lmo_models, lmo_frames):
    """(frame, image, its well visible instances, viewpoint models) of the first frame."""
    frame = lmo_frames[0]
    truths = [i for i in frame.instances if i.visib_fract > 0.5]
    names = sorted({i.object_name for i in truths})
    models = load_viewpoint_models({n: lmo_models[n] for n in names}, progress=False)
    return frame, frame.load_image(), truths, models


def stream_tracker(scene, lmo_models, in_place=None, **settings):
    """
    Make a stream-mode PoseTracker over a gated ground-truth detector and rotations.

    ``in_place``: a detector for a second pipeline of the same stages, the tracker's
    in-place route.
    """
    frame, _, truths, models = scene
    detector = GatedDetector(truths)
    by_name = {i.object_name: i.rotation for i in truths}

    def rotations(image_rgb, camera, detections):
        return np.stack([by_name[d.object_name] for d in detections])

    options = PipelineOptions(tracking=True, tracking_stream=True, tracking_min_score=0.3,
                              **settings)
    objects = {n: lmo_models[n] for n in models}
    pipeline = PosePipeline(objects, options, detector, rotations,
                            refiner=PoseRefiner(models, options))
    second = None if in_place is None else PosePipeline(objects, options, in_place, rotations,
                                                        refiner=pipeline.refiner)
    return PoseTracker(pipeline, second), detector


def wait_for(condition, limit_s=WAIT_S):
    """Wait until ``condition()`` holds."""
    start = time.monotonic()
    while not condition():
        assert time.monotonic() - start < limit_s, 'never happened'
        time.sleep(0.01)


def run_until(tracker, image, camera, done, stamp=lambda: None, limit_s=WAIT_S):
    """Answer frames (stamped ``stamp()``) until ``done(result)``; return every result."""
    results, start = [], time.monotonic()
    while time.monotonic() - start < limit_s:
        results.append(tracker.estimate(image, camera, stamp()))
        if done(results[-1]):
            return results
        time.sleep(0.01)
    raise AssertionError('stream mode never got there')


def lose_track(tracker, name):
    """Move the track of ``name`` 0.3 m off its object: the next frame's tracking loses it."""
    track = tracker.tracks[name]
    tracker.tracks[name] = Track(replace(track.pose, translation=track.pose.translation + 0.3))


def names_of(poses):
    """Return the sorted object names of poses or ground-truth instances."""
    return sorted(p.object_name for p in poses)


def test_stream_answers_every_frame_and_adopts_later(scene, lmo_models):
    frame, image, truths, _ = scene
    tracker, detector = stream_tracker(scene, lmo_models, tracking_redetect_every=3)
    stamps = iter(np.arange(1.0, 100.0, 1.0 / 200.0))     # a camera faster than the pipeline
    try:
        # The first frame has nothing else to answer from: it is detected in the frame.
        detector.gate.set()
        first = tracker.estimate(image, frame.camera, next(stamps))
        assert names_of(first.poses) == names_of(truths) and 'detector' in first.timings_ms
        # The detector is held: every frame is answered by the tracks, none waits for it;
        # the third hands its frame to the full pipeline beside them.
        detector.gate.clear()
        for _ in range(5):
            start = time.perf_counter()
            result = tracker.estimate(image, frame.camera, next(stamps))
            assert time.perf_counter() - start < 1.0
            assert names_of(result.poses) == names_of(truths)
            assert 'detector' not in result.timings_ms
        wait_for(lambda: detector.calls == 2)
        assert tracker.background_running
        detector.gate.set()
        results = run_until(tracker, image, frame.camera,
                            lambda r: 'stream_job' in r.timings_ms, lambda: next(stamps))
        adopted = results[-1]
        assert names_of(adopted.poses) == names_of(truths)
        assert {'stream_age', 'tracking'} <= set(adopted.timings_ms)
        assert adopted.timings_ms['stream_age'] >= adopted.timings_ms['stream_job'] > 0.0
        # Later frames keep them by tracking; the full pipeline runs beside, one job at a time.
        for _ in range(8):
            later = tracker.estimate(image, frame.camera, next(stamps))
            assert names_of(later.poses) == names_of(truths)
            assert 'detector' not in later.timings_ms
        assert detector.most_running == 1
    finally:
        tracker.reset()
    assert not tracker.background_running


def test_stream_replaces_a_lost_track(scene, lmo_models):
    frame, image, truths, _ = scene
    tracker, detector = stream_tracker(scene, lmo_models, tracking_redetect_every=1000)
    detector.gate.set()
    try:
        run_until(tracker, image, frame.camera, lambda r: r.poses)
        calls = detector.calls
        name = truths[0].object_name
        # Far off the object: the next frame's tracking loses it, and hands the frame on.
        lose_track(tracker, name)
        lost = tracker.estimate(image, frame.camera)
        assert name not in {p.object_name for p in lost.poses}
        results = run_until(tracker, image, frame.camera,
                            lambda r: name in {p.object_name for p in r.poses})
        assert detector.calls > calls and 'stream_job' in results[-1].timings_ms
    finally:
        tracker.reset()


@pytest.mark.parametrize('indices, in_frame', [
    ((None, None), True),       # a frame a second, the stamps say: slower than the pipeline
    ((0, 200), False),          # 200 frames in that second, dropped before: faster
])
def test_the_camera_period_decides_where_a_lost_track_is_detected(scene, lmo_models,
                                                                  indices, in_frame):
    frame, image, truths, _ = scene
    tracker, detector = stream_tracker(scene, lmo_models, tracking_redetect_every=1000)
    detector.gate.set()
    try:
        first = tracker.estimate(image, frame.camera, 1.0, indices[0])
        assert names_of(first.poses) == names_of(truths) and detector.calls == 1
        name = truths[0].object_name
        lose_track(tracker, name)
        found = tracker.estimate(image, frame.camera, 2.0, indices[1])
        assert ('detector' in found.timings_ms) == in_frame
        assert (name in {p.object_name for p in found.poses}) == in_frame
        wait_for(lambda: detector.calls == 2)       # in the frame, or beside it
    finally:
        tracker.reset()


def test_the_in_place_route_detects_while_the_period_holds_it(scene, lmo_models,
                                                              monkeypatch):
    monkeypatch.setattr(stream_schedule, 'IN_PLACE_RETRY_EVERY', 3)
    compile_kernels()       # the first frame's run time is the refinement's, not numba's
    frame, image, truths, _ = scene
    slow = GatedDetector(truths, delay_s=2.0)       # the in-place route: two seconds a frame
    tracker, detector = stream_tracker(scene, lmo_models, in_place=slow,
                                       tracking_redetect_every=1000)
    detector.gate.set()
    slow.gate.set()
    name = truths[0].object_name

    def lost_and_found(stamp):
        """Lose a track, answer a frame stamped ``stamp``; return (shipped, in-place) runs."""
        lose_track(tracker, name)
        found = tracker.estimate(image, frame.camera, stamp)
        assert name in {p.object_name for p in found.poses}
        return detector.calls, slow.calls

    try:
        # The first frame (no period yet) takes the shipped route.
        tracker.estimate(image, frame.camera, 1.0)
        assert (detector.calls, slow.calls) == (1, 0)
        # A frame a second holds the shipped route; the in-place one, its run time not
        # known yet, is tried and takes longer than the period.
        assert lost_and_found(2.0) == (1, 1)
        # The shipped route detects the next frames in place, until the in-place route is
        # tried again (every third such frame here).
        assert lost_and_found(3.0) == (2, 1)
        assert lost_and_found(4.0) == (3, 1)
        assert lost_and_found(5.0) == (3, 2)
        # Five seconds a frame, no more retries: the running mean of the period grows until
        # it holds the in-place route.
        monkeypatch.setattr(stream_schedule, 'IN_PLACE_RETRY_EVERY', 1000)
        assert lost_and_found(10.0) == (4, 2)       # a mean of 1.8 s
        assert lost_and_found(15.0) == (5, 2)       # 2.44 s
        assert lost_and_found(20.0) == (5, 3)       # 2.95 s: above 1.25 x 2 s
    finally:
        tracker.reset()


def test_the_in_place_route_must_share_the_refiner(scene, lmo_models):
    tracker, _ = stream_tracker(scene, lmo_models)
    other = PosePipeline(tracker.pipeline.models, tracker.options, None, None,
                         refiner=PoseRefiner(tracker.pipeline.refiner.viewpoint_models,
                                             tracker.options))
    with pytest.raises(InputError, match='share the tracked refiner'):
        PoseTracker(tracker.pipeline, other)


def test_the_loader_builds_the_in_place_route_with_the_stages_it_uses(lmo_models, tmp_path):
    options = PipelineOptions(tracking=True, tracking_stream=True, inference_threads=1)
    tracker = load_pipeline(lmo_models, options)
    shipped, in_place = tracker.pipeline, tracker.in_place
    assert in_place.options.pose_source == 'dense+qnet' and shipped.options.pose_source == 'qnet'
    assert shipped.correspondences is None and in_place.correspondences is not None
    assert in_place.detector is shipped.detector and in_place.refiner is shipped.refiner
    assert in_place.rotation_estimator is shipped.rotation_estimator is not None
    # A dense route keeps running without Q-Net beside an in-place route that uses it.
    dense = load_pipeline(lmo_models, replace(options, pose_source='dense'))
    assert dense.pipeline.rotation_estimator is None
    assert dense.in_place.rotation_estimator is not None
    # An object the shipped dense net lacks (one added with its own detector and Q-Net):
    # logged, and the in-place route left out.
    torch.manual_seed(0)
    objects = ('ape', 'stranger')
    named = WeightFiles(detector=tmp_path / 'detector.pt', qnet=tmp_path / 'qnet.pt')
    save_weights(named.detector, CenterBoxNet(DetectorConfig(objects)), 'detector', {'test': 1})
    save_weights(named.qnet, QNet(QNetConfig(objects)), 'qnet', {'test': 1})
    added = {'ape': lmo_models['ape'], 'stranger': lmo_models['ape']}
    lines = []
    alone = load_pipeline(added, options, named, log=lines.append)
    assert alone.in_place is None and alone.pipeline.correspondences is None
    assert any('tracking_in_place_pose_source dense+qnet needs the dense net' in line
               and 'stranger' in line for line in lines)
    # A dense file the user names must load, for either route.
    partial = tmp_path / 'dense_ape.pt'
    save_weights(partial, DenseNet(DenseConfig(('ape',), crop_size=32, channels=16)), 'dense',
                 {'test': 1})
    for pose_source in ('qnet', 'dense'):
        with pytest.raises(InputError, match='lacks'):
            load_pipeline(lmo_models, replace(options, pose_source=pose_source),
                          WeightFiles(dense=partial))
    # Where pose_source already is the in-place route, there is one pipeline.
    same = replace(options, tracking_in_place_pose_source='qnet')
    assert load_pipeline(lmo_models, same).in_place is None


def test_reset_stops_the_background_job(scene, lmo_models):
    frame, image, _, _ = scene
    tracker, detector = stream_tracker(scene, lmo_models, tracking_redetect_every=1)
    stamps = iter(np.arange(1.0, 100.0, 1.0 / 200.0))
    detector.gate.set()
    tracker.estimate(image, frame.camera, next(stamps))     # detected in the frame
    detector.gate.clear()
    tracker.estimate(image, frame.camera, next(stamps))     # handed on, held
    assert tracker.background_running
    threading.Timer(0.2, detector.gate.set).start()     # the job in hand ends soon
    tracker.reset()
    assert not tracker.background_running and tracker.tracks == {}
    assert not [t for t in threading.enumerate() if t.name == 'bbpose_detection']
    # Its poses are dropped; after the reset a new stream starts: detected in the frame.
    again = tracker.estimate(image, frame.camera, 0.5)
    assert again.poses and 'detector' in again.timings_ms and not tracker.background_running
    tracker.close()
    closed = tracker.estimate(image, frame.camera, 0.6)      # the tracks alone answer
    assert 'detector' not in closed.timings_ms and not tracker.background_running


def test_stream_needs_tracking():
    with pytest.raises(InputError, match='tracking_stream / tracking'):
        PipelineOptions(tracking_stream=True)
    assert not PipelineOptions().tracking_stream


def test_parallel_kernels_launch_safely():
    compile_kernels()       # a parallel kernel has run: numba has chosen its layer
    layer = numba.threading_layer()
    assert kernel_launch.concurrent_launches_safe() == (layer != 'workqueue')
    lock = kernel_launch.parallel_launch()
    assert (lock is kernel_launch._LAUNCHES) == (layer == 'workqueue')


def test_stage_rates():
    frames = [(t * 0.1, {'total': 1.0, **({'stream_job': 5.0} if t % 4 == 0 else {})})
              for t in range(41)]
    rates = stage_rates(frames)
    assert rates['total'] == pytest.approx(10.0, rel=0.03)
    assert rates['stream_job'] == pytest.approx(2.5, rel=0.1)
    assert stage_rates(frames[:1]) == {}
