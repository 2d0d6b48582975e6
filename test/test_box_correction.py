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

"""The amodal box corrected from the dense net's amodal mask (``box_correction``)."""

import numpy as np
import pytest

from bbpose_ros.core.eval.detection import score_detections
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.nets.crops import extract_crops, square_boxes
from bbpose_ros.core.pipeline.box_correction import (corrected_box, corrected_detections,
                                                     crop_region, mask_box_cells, mask_box_uv)
from bbpose_ros.core.pipeline.correspondences import DenseMaps
from bbpose_ros.core.pipeline.loader import load_correspondences, load_pipeline
from bbpose_ros.core.pipeline.pose_pipeline import PosePipeline
from bbpose_ros.core.pipeline.poses import Detection
from bbpose_ros.core.util.errors import InputError

FRAMES = 100    # the dev frames


def cell_shares(low, high, size=32):
    """(size,) share of each unit cell [j, j + 1] that the interval [low, high] covers."""
    cells = np.arange(size)
    return np.clip(np.minimum(cells + 1.0, high) - np.maximum(cells, low), 0.0, 1.0)


def rectangle(x, y, size=32):
    """(size, size) cell shares of the rectangle x[0]..x[1] by y[0]..y[1] (cell units)."""
    return np.outer(cell_shares(*y, size), cell_shares(*x, size))


@pytest.mark.parametrize('x, y', [((5.3, 20.7), (8.2, 25.9)), ((4.5, 27.5), (3.0, 29.0)),
                                  ((10.9, 11.95), (6.05, 18.5))])
def test_the_box_of_a_rectangle_is_found_within_a_tenth_of_a_cell(x, y):
    box = mask_box_cells(rectangle(x, y))
    # Linear between cell centres: exact where an edge passes a centre or a cell edge, off
    # by at most 1.5 - sqrt(2) cell between.
    np.testing.assert_allclose(box, [x[0], y[0], x[1], y[1]], atol=1.5 - np.sqrt(2) + 1e-9)


def test_edges_through_cell_centres_are_exact_and_not_on_the_grid():
    box = mask_box_cells(rectangle((6.5, 17.5), (2.5, 30.5)))
    np.testing.assert_allclose(box, [6.5, 2.5, 17.5, 30.5], atol=1e-9)


def test_sides_that_run_out_of_the_grid_or_an_empty_mask_are_unknown():
    box = mask_box_cells(rectangle((0.0, 20.2), (4.3, 32.0)))
    assert np.isnan(box[0]) and np.isnan(box[3])
    np.testing.assert_allclose(box[[1, 2]], [4.3, 20.2], atol=0.09)
    assert np.all(np.isnan(mask_box_cells(np.full((32, 32), 0.2))))


def test_the_box_in_frame_pixels_keeps_the_detectors_unknown_sides():
    region = np.array([99.5, 49.5, 163.5, 113.5])       # 64 px: two pixels a cell
    share = rectangle((0.0, 20.25), (4.25, 30.0))
    np.testing.assert_allclose(mask_box_uv(share, region)[1:],
                               [49.5 + 8.5, 99.5 + 40.5, 49.5 + 60.0], atol=0.2)
    detector = np.array([95.0, 60.0, 145.0, 105.0])
    box = corrected_box(detector, share, region)
    assert box[0] == detector[0]
    np.testing.assert_allclose(box[1:], [58.0, 140.0, 109.5], atol=0.2)
    # A mask box far from the detector's (a tiny blob) is not trusted.
    blob = rectangle((15.0, 16.0), (15.0, 16.0))
    np.testing.assert_array_equal(corrected_box(detector, blob, region), detector)


def test_crop_region_is_the_pixels_extract_crops_cuts():
    image = np.zeros((480, 640, 3), dtype=np.uint8)
    for square in ([100.2, 50.7, 170.9, 121.4], [10.0, 20.0, 250.6, 260.6]):
        region = crop_region(square, 64)
        x0, y0 = int(region[0] + 0.5), int(region[1] + 0.5)
        side = int(round(region[2] - region[0]))
        image[:] = 0
        image[y0:y0 + side, x0:x0 + side] = 255
        crop = extract_crops(image, [square], 64)[0]
        assert np.all(crop == 255), square
        assert abs(side - (square[2] - square[0])) <= 1.0 + 0.01 * side


def test_corrected_detections_keep_order_object_and_score():
    detections = [Detection('ape', 0.9, np.array([100.0, 50.0, 150.0, 110.0])),
                  Detection('cat', 0.4, np.array([300.0, 200.0, 340.0, 230.0]))]
    squares = square_boxes(np.stack([d.box_uv for d in detections]), 1.2)
    amodal = np.stack([rectangle((3.0, 29.0), (2.5, 28.0)), np.zeros((32, 32))])
    corrected = corrected_detections(detections, amodal, squares, 64)
    assert [(d.object_name, d.score) for d in corrected] == [('ape', 0.9), ('cat', 0.4)]
    region = crop_region(squares[0], 64)
    cell = (region[2] - region[0]) / 32
    np.testing.assert_allclose(corrected[0].box_uv, region[[0, 1, 0, 1]]
                               + cell * np.array([3.0, 2.5, 29.0, 28.0]), atol=0.1 * cell)
    np.testing.assert_array_equal(corrected[1].box_uv, detections[1].box_uv)


class FakeDense:
    """Stands in for the dense stage: one amodal rectangle per crop."""

    class config:           # noqa: N801 (mirrors DenseConfig's attributes)
        crop_size = 64
        context = 1.2

    def __init__(self, cells):
        self.cells = cells

    def maps(self, image_rgb, detections):
        squares = square_boxes(np.stack([d.box_uv for d in detections]), 1.2)
        amodal = np.stack([rectangle(*self.cells) for _ in detections])
        return DenseMaps(np.zeros((len(detections), 32, 32, 3)), amodal, amodal, squares)


def test_the_pipeline_solves_with_the_corrected_box(lmo_models):
    camera = CameraIntrinsics(572.4, 573.6, 325.3, 242.0, 640, 480)
    model = lmo_models['ape']
    rotation = np.eye(3)
    detection = Detection('ape', 0.9, np.array([300.0, 220.0, 350.0, 262.0]))
    image = np.zeros((480, 640, 3), dtype=np.uint8)
    runs = {}
    for source in ('detector', 'dense_mask', 'both'):
        options = PipelineOptions(refine=False, box_source=source)
        pipeline = PosePipeline({'ape': model}, options,
                                correspondences=FakeDense(((2.0, 30.0), (3.0, 29.0))))
        result = pipeline.estimate(image, camera, [detection], rotation[None])
        runs[source] = result.poses[0]
    expected = corrected_box(detection.box_uv, rectangle((2.0, 30.0), (3.0, 29.0)),
                             crop_region(square_boxes(detection.box_uv, 1.2)[0], 64))
    np.testing.assert_array_equal(runs['dense_mask'].detection.box_uv, expected)
    np.testing.assert_array_equal(runs['detector'].detection.box_uv, detection.box_uv)
    # The corrected box is larger here, so the object is solved nearer the camera.
    assert runs['dense_mask'].translation[2] < runs['detector'].translation[2]
    np.testing.assert_array_equal(runs['both'].translation, runs['dense_mask'].translation)
    with pytest.raises(InputError, match='box_source'):
        PosePipeline({'ape': model}, PipelineOptions(refine=False, box_source='dense_mask'))


def test_box_correction_makes_the_dense_net_run_with_the_rotations_given():
    options = PipelineOptions(refine=False, box_source='dense_mask')
    assert options.runs_dense() and options.runs_dense(rotations_given=True)
    assert not PipelineOptions(refine=False).runs_dense(rotations_given=True)


@pytest.mark.slow   # the detector and the dense net on the 100 dev frames, ~20 s
def test_corrected_boxes_are_nearer_the_truth_than_the_detectors(lmo_models, lmo_frames):
    options = PipelineOptions(refine=False, inference_threads=2)
    detector = load_pipeline(lmo_models, options).detector
    dense = load_correspondences(lmo_models, options)
    frames = lmo_frames[:FRAMES]
    found, corrected = [], []
    for frame in frames:
        image = frame.load_image()
        detections = detector(image)
        found.append(detections)
        maps = dense.maps(image, detections)
        corrected.append(corrected_detections(detections, maps.amodal, maps.squares_uv,
                                              dense.config.crop_size))
    names = list(lmo_models)
    before = score_detections(frames, found, names)['detection']
    after = score_detections(frames, corrected, names)['detection']

    def errors(report, key):
        values = np.array([report[name][key] for name in names], dtype=float)
        return values[np.isfinite(values)]
    # Per object, the boxes' median size error (signed) comes nearer 0, and the sides'
    # scatter shrinks.
    assert np.mean(np.abs(errors(after, 'size_error_median'))) < \
        np.mean(np.abs(errors(before, 'size_error_median')))
    assert np.mean(errors(after, 'side_error_rms')) < np.mean(errors(before, 'side_error_rms'))
