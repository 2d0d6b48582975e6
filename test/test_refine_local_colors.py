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

"""Local colour models (RBOT's): the real frames' true contours stay where they are."""

import numpy as np
import pytest

from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.refine.color_histograms import color_bins
from bbpose_ros.core.refine.refiner import refine_poses
from bbpose_ros.core.refine.region_modality import RegionModality
from bbpose_ros.core.refine.viewpoint_cache import load_viewpoint_models
from bbpose_ros.core.util.errors import InputError

pytestmark = pytest.mark.slow   # viewpoint models of every mesh, 20 real frames refined

FRAMES = 20
LOCAL_LINES = 8


@pytest.fixture(scope='module')
def truths(lmo_models, lmo_frames):
    """Per sampled dev frame: (colour bins, camera, models, rotations, translations)."""
    models = load_viewpoint_models(lmo_models, progress=False)
    scenes = []
    for frame in lmo_frames[::max(1, len(lmo_frames) // FRAMES)][:FRAMES]:
        instances = [i for i in frame.instances
                     if i.object_name in models and i.visib_fract >= 0.1]
        if instances:
            scenes.append((color_bins(frame.load_image()), frame.camera,
                           [models[i.object_name] for i in instances],
                           np.stack([i.rotation for i in instances]),
                           np.stack([i.translation for i in instances])))
    return scenes


def _pull_px(scenes, window):
    """(lines,) each valid line's contour mean at scale 1 with the colours of the truth, px."""
    pulls = []
    for bins, camera, models, rotation, translation in scenes:
        modality = RegionModality(models, bins, camera, 3.0,
                                  options=PipelineOptions(refine_local_colors=window),
                                  occlusions=(np.arange(len(models)),
                                              np.ones(len(models), bool)))
        hist_f, hist_b, _, local = modality.local_colors(rotation, translation)
        lines = modality.lines(rotation, translation, hist_f, hist_b, 1, local=local)
        pulls.append(lines.mean[lines.valid])
    return np.concatenate(pulls)


def _along_ray_mm(scenes, window):
    """(poses,) the refined translation's error along the true viewing ray, mm (+: away)."""
    errors = []
    for bins, camera, models, rotation, translation in scenes:
        results = refine_poses(bins, camera, models, rotation, translation,
                               PipelineOptions(refine_local_colors=window),
                               instances=range(len(models)))
        for result, truth in zip(results, translation):
            ray = truth / np.linalg.norm(truth)
            errors.append(1000.0 * float((result.translation - truth) @ ray))
    return np.array(errors)


def test_local_colours_keep_the_true_contour_in_place(truths):
    # One colour model gathered all around the object makes a dark object's own colours
    # ambiguous against dark shadows and clutter elsewhere: at the truth the lines put the
    # contour inside the silhouette. Each line's neighbours' colours do not.
    assert np.mean(_pull_px(truths, 0)) < -0.07
    assert np.mean(_pull_px(truths, LOCAL_LINES)) > -0.06


def test_local_colours_hold_the_depth_of_the_truth(truths):
    # Refined from the truth, the one-model refiner pushes the objects away from the camera.
    assert np.median(_along_ray_mm(truths, 0)) > 4.0
    assert np.median(_along_ray_mm(truths, LOCAL_LINES)) < 3.0


def test_local_colours_are_the_global_ones_without_samples(truths):
    bins, camera, models, rotation, translation = truths[0]
    modality = RegionModality(models, bins, camera, 3.0,
                              options=PipelineOptions(refine_local_colors=LOCAL_LINES))
    hist_f, hist_b, _, local = modality.local_colors(rotation, translation)
    assert local.counts.sum() > 0
    local.counts[:] = 0     # a pose without samples (a track's): its global colours alone
    with_local = modality.lines(rotation, translation, hist_f, hist_b, 1, local=local)
    without = modality.lines(rotation, translation, hist_f, hist_b, 1)
    np.testing.assert_allclose(with_local.mean, without.mean, atol=1e-6)
    with pytest.raises(InputError, match='refine_local_colors'):
        PipelineOptions(refine_local_colors=-1)
