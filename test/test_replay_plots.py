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

"""Charts (core.eval.plots) and overlays (core.pipeline.overlays) on exact LM-O poses."""

import cv2
import numpy as np

from bbpose_ros.core.eval import plots
from bbpose_ros.core.eval.instance_scores import score_frame, summarize_objects
from bbpose_ros.core.pipeline import overlays
from bbpose_ros.core.pipeline.poses import Detection, PoseEstimate
from bbpose_ros.core.util.files import write_rgb_png


def test_charts_and_overlays_are_written(lmo_frames, lmo_models, tmp_path):
    scores = {name: [] for name in lmo_models}
    frame = lmo_frames[0]
    counted = [i for i in frame.instances if i.visib_fract >= 0.1]
    exact = [PoseEstimate(Detection(i.object_name, 0.9, i.box_uv), i.rotation, i.translation)
             for i in counted]
    for score in score_frame(lmo_models, counted, exact, frame.camera):
        scores[score.object_name].append(score)
    per_object = summarize_objects(scores)['objects']
    assert all(per_object[i.object_name]['add_s_recall'] == 1.0 for i in counted)
    plots.recall_curves(scores, tmp_path / 'curves.png')
    plots.object_bars(per_object, tmp_path / 'bars.png')

    image = frame.load_image()
    debug = overlays.draw_estimates(image, frame.camera, lmo_models, exact)
    truths = [(i.object_name, i.rotation, i.translation) for i in counted]
    write_rgb_png(tmp_path / 'overlay.png', overlays.draw_comparison(
        image, frame.camera, lmo_models, truths, truths))
    assert debug.shape == image.shape and not np.array_equal(debug, image)
    for name in ('curves.png', 'bars.png', 'overlay.png'):
        assert cv2.imread(str(tmp_path / name)) is not None, name


def test_object_colours_are_distinct_for_linemod():
    colours = [overlays.object_color(obj_id) for obj_id in range(1, 16)]
    assert len(set(colours)) == 15
