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
CameraInfo -> CameraModel: K or P, binning and ROI, distortion rectified.

LM-O frames are re-distorted with a known D (each raw pixel takes the pinhole image's
colour where the model sends it) and given to the pipeline with that CameraInfo: they must
give the poses of the original frames, within the tolerance docs/reliability.md measures.
"""

from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.camera_info import camera_model, CameraModel, Rectifier
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.pipeline.loader import load_pipeline
from bbpose_ros.core.util.errors import InputError

# Distortions of the kind a calibration gives, several to tens of pixels at the corners.
DISTORTIONS = {
    'plumb_bob': [-0.28, 0.09, 0.001, -0.0005, 0.0],
    'rational_polynomial': [0.3, -0.1, 0.0008, -0.0006, 0.0, 0.55, -0.05, 0.0],
    'equidistant': [0.02, -0.01, 0.0, 0.0],
}
# Median pose change over the instances of every 8th LM-O frame (docs/reliability.md): the
# pipeline's own response to resampling an image is of this size.
TOLERANCE_MM, TOLERANCE_DEG = 35.0, 13.0


def info(k, width=640, height=480, d=(), model='plumb_bob', p=None, r=None, binning=(0, 0),
         roi=(0, 0, 0, 0)):
    """Make a CameraInfo-like object (the core reads fields only)."""
    k = np.asarray(k, dtype=float).reshape(3, 3)
    p = np.hstack([k, np.zeros((3, 1))]) if p is None else np.asarray(p, dtype=float)
    return SimpleNamespace(
        k=k.ravel().tolist(), p=p.ravel().tolist(), d=list(d), distortion_model=model,
        r=(np.eye(3) if r is None else np.asarray(r)).ravel().tolist(), width=width,
        height=height, binning_x=binning[0], binning_y=binning[1],
        roi=SimpleNamespace(x_offset=roi[0], y_offset=roi[1], width=roi[2], height=roi[3]))


K = [[572.4, 0.0, 325.3], [0.0, 573.6, 242.0], [0.0, 0.0, 1.0]]


def test_binning_and_roi_map_full_resolution_pixels_to_the_image():
    model = camera_model(info(K, binning=(2, 2), roi=(100, 60, 400, 300)), 200, 150)
    camera = model.intrinsics
    assert not model.needs_rectification and (camera.width, camera.height) == (200, 150)
    points = np.array([[0.05, -0.02, 0.7], [-0.1, 0.08, 1.3]])
    full = CameraIntrinsics.from_k(K, 640, 480).project(points)
    # pixel centres of a 2x2 bin: full (u, v) -> ((u - x0 + 0.5) / 2 - 0.5, ...)
    expected = (full - (100, 60) + 0.5) / 2 - 0.5
    assert np.allclose(camera.project(points), expected, atol=1e-9)


def test_k_or_p_and_a_resized_stream():
    p = np.hstack([np.array(K) * [[0.9], [0.9], [1.0]], np.zeros((3, 1))])
    distorted = info(K, d=DISTORTIONS['plumb_bob'], p=p)
    assert camera_model(distorted, 640, 480, rectified=True).intrinsics.fx == p[0, 0]
    assert camera_model(distorted, 640, 480).intrinsics.fx == p[0, 0]    # rectified to P
    assert camera_model(info(K), 640, 480).intrinsics.fx == K[0][0]
    assert camera_model(info(K), 320, 240).intrinsics.fx == K[0][0] / 2


def test_zero_d_or_an_unknown_model_without_d_needs_no_rectification():
    for case in (info(K, d=[0.0] * 5), info(K, d=[], model=''), info(K, d=[], model='fov')):
        assert not camera_model(case, 640, 480).needs_rectification


@pytest.mark.parametrize('case, words', [
    (info(K, d=[0.1, 0.0, 0.0, 0.0], model='fov'), 'field distortion_model "fov"'),
    (info(K, d=[0.1, 0.0, 0.0]), 'field d holds 3 coefficients; plumb_bob takes 4 or 5'),
    (info(K, d=[0.1, np.nan, 0.0, 0.0, 0.0]), 'field d holds nan'),
    (info(np.zeros((3, 3))), 'field k is all zero'),
    (info(K, p=np.hstack([np.array(K) * 1.1, np.zeros((3, 1))])), 'fields k and p disagree'),
    (info(K, width=800, height=800), 'fields width, height, roi and binning say 800x800'),
    (info(K, roi=(600, 0, 100, 480)), 'field roi'),
])
def test_bad_camera_info_names_the_field(case, words):
    with pytest.raises(InputError, match=words):
        camera_model(case, 640, 480)


def test_the_rectifier_makes_its_maps_once_per_camera_info(lmo_frames, monkeypatch):
    made = []
    original = CameraModel.rectification_maps
    monkeypatch.setattr(CameraModel, 'rectification_maps',
                        lambda model: made.append(model) or original(model))
    image = lmo_frames[0].load_image()
    rectifier = Rectifier()
    for d in (DISTORTIONS['plumb_bob'], DISTORTIONS['plumb_bob'], [-0.1, 0.0, 0.0, 0.0, 0.0],
              [-0.1, 0.0, 0.0, 0.0, 0.0]):
        rectifier(image, camera_model(info(K, d=d), 640, 480))   # a new message each time
    assert len(made) == 2


def redistortion_maps(name, k):
    """For each raw pixel, where the pinhole (LM-O) image holds its colour: (x, y) float32."""
    d = np.array(DISTORTIONS[name])
    u, v = np.meshgrid(np.arange(640.0), np.arange(480.0))
    raw = np.stack([u, v], axis=-1).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)
    undistort = cv2.fisheye.undistortPoints if name == 'equidistant' else cv2.undistortPoints
    pinhole = undistort(raw, k, d, None, None, k, criteria).reshape(480, 640, 2)
    return pinhole[..., 0].astype(np.float32), pinhole[..., 1].astype(np.float32)


@pytest.fixture(scope='module')
def redistorted(lmo_frames):
    """(frames, original images, {model: re-distorted images}) of every 8th LM-O frame."""
    frames = lmo_frames[::8]
    assert all(np.array_equal(f.camera.k, frames[0].camera.k) for f in frames)
    originals = [frame.load_image() for frame in frames]
    out = {}
    for name in DISTORTIONS:
        maps = redistortion_maps(name, frames[0].camera.k)
        out[name] = [cv2.remap(image, *maps, cv2.INTER_LINEAR) for image in originals]
    return frames, originals, out


def pose_changes(pipeline, frames, originals, images, model):
    """Per instance found in both: (translation change mm, rotation change deg)."""
    rectifier, changes = Rectifier(), []
    for frame, original, image in zip(frames, originals, images):
        before = pipeline.estimate(original, frame.camera).poses
        after = pipeline.estimate(rectifier(image, model), model.intrinsics).poses
        for a in before:
            for b in after:
                if a.object_name == b.object_name:
                    cos = (np.trace(a.rotation.T @ b.rotation) - 1.0) / 2.0
                    changes.append((1e3 * np.linalg.norm(a.translation - b.translation),
                                    np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))))
    return np.array(changes)


@pytest.mark.parametrize('name', list(DISTORTIONS))
def test_rectified_images_come_back_to_the_originals(redistorted, name):
    frames, originals, images = redistorted
    k = frames[0].camera.k
    model = camera_model(info(k, d=DISTORTIONS[name], model=name), 640, 480)
    assert model.needs_rectification and np.allclose(model.intrinsics.k, k, atol=1e-9)
    inner = np.s_[40:-40, 40:-40]
    back = [np.abs(Rectifier()(image, model)[inner].astype(int) - original[inner]).mean()
            for image, original in zip(images[name], originals)]
    raw = [np.abs(image[inner].astype(int) - original[inner]).mean()
           for image, original in zip(images[name], originals)]
    assert max(back) < 4.0 and min(raw) > 3 * max(back)


@pytest.mark.slow   # the pipeline on redistorted real frames, ~8 s each
@pytest.mark.parametrize('name', list(DISTORTIONS))
def test_redistorted_frames_give_the_poses_of_the_originals(redistorted, lmo_models, name):
    frames, originals, images = redistorted
    # The float networks: the int8 graphs answer the resampling itself with larger pose
    # changes (docs/experiments.md), which would blur what this test checks.
    pipeline = load_pipeline(lmo_models, PipelineOptions(refine=False, inference_threads=1,
                                                         inference_precision='fp32'))
    k = frames[0].camera.k
    rectify = camera_model(info(k, d=DISTORTIONS[name], model=name), 640, 480)
    ignore = camera_model(info(k), 640, 480)              # the distortion left in
    rectified = pose_changes(pipeline, frames, originals, images[name], rectify)
    left_in = pose_changes(pipeline, frames, originals, images[name], ignore)
    assert len(rectified) >= 50
    assert np.median(rectified[:, 0]) < TOLERANCE_MM
    assert np.median(rectified[:, 1]) < TOLERANCE_DEG
    assert np.median(left_in[:, 0]) > 2 * np.median(rectified[:, 0])
