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

"""The moderngl renderer against the numpy z-buffer oracle, on LM-O meshes."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bbpose_ros.core.geometry.boxes import mask_box_uv
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.projection import projected_box_uv
from bbpose_ros.core.render import Draw, Lighting, MeshRenderer, opengl_projection, RenderMesh
from bbpose_ros.core.render.reference import render_depth, render_silhouette

pytestmark = pytest.mark.slow   # renders with OpenGL

CAMERA = CameraIntrinsics(572.4114, 573.57043, 325.2611, 242.04899, 640, 480)
NAMES = ('ape', 'driller')


@pytest.fixture(scope='module')
def renderer(egl, lmo_models):
    """Build a MeshRenderer of the ape and the driller."""
    renderer = MeshRenderer(CAMERA, {name: RenderMesh.from_object_model(lmo_models[name])
                                     for name in NAMES})
    yield renderer
    renderer.close()


def random_pose(rng, inside=True):
    """Draw a random rotation and a translation 0.4-1.2 m away, near or off the centre."""
    spread = 0.08 if inside else 0.35
    translation = np.array([rng.uniform(-spread, spread), rng.uniform(-spread, spread),
                            rng.uniform(0.4, 1.2)])
    return Rotation.random(random_state=rng).as_matrix(), translation


def test_projection_matches_camera_convention():
    rng = np.random.default_rng(0)
    points = rng.uniform([-0.3, -0.2, 0.5], [0.3, 0.2, 2.0], (20, 3))
    clip = np.c_[points, np.ones(20)] @ opengl_projection(CAMERA, 0.01, 20.0).T
    ndc = clip[:, :3] / clip[:, 3:]
    # GL window coordinate w = (ndc + 1) / 2 * size; OpenCV pixel coordinate = w - 0.5.
    uv = (ndc[:, :2] + 1.0) / 2.0 * [CAMERA.width, CAMERA.height] - 0.5
    np.testing.assert_allclose(uv, CAMERA.project(points), atol=1e-9)
    assert np.all(np.abs(ndc[:, 2]) < 1.0)


@pytest.mark.parametrize('name', NAMES)
def test_silhouette_matches_reference(renderer, lmo_models, name):
    model = lmo_models[name]
    rng = np.random.default_rng(1)
    for _ in range(3):
        rotation, translation = random_pose(rng)
        result = renderer.render([Draw(name, rotation, translation)], Lighting(), [0])
        mask = result.instance_ids == 1
        reference = render_silhouette(CAMERA, model.vertices, model.faces, rotation,
                                      translation)
        assert (mask & reference).sum() / (mask | reference).sum() > 0.995
        np.testing.assert_allclose(mask_box_uv(mask), mask_box_uv(reference), atol=1.0)
        # Pixel centres inside the projected vertices' extremes: the mask box is within 1 px.
        np.testing.assert_allclose(
            mask_box_uv(mask), projected_box_uv(CAMERA, model.vertices, rotation, translation),
            atol=1.0)
        np.testing.assert_array_equal(result.full_masks[0], mask)
        assert result.full_pixel_counts[0] == mask.sum()
        assert result.rgb[mask].max() > 0 and result.rgb[~mask].max() == 0


def test_full_mask_counts_pixels_outside_the_image(renderer, lmo_models):
    model = lmo_models['driller']
    rotation = Rotation.from_euler('xyz', [30, 60, 10], degrees=True).as_matrix()
    translation = np.array([0.3, 0.0, 0.6])  # cut by the right image border
    result = renderer.render([Draw('driller', rotation, translation)], Lighting(), [0])
    reference = render_silhouette(CAMERA, model.vertices, model.faces, rotation, translation)
    assert (result.full_masks[0] ^ reference).sum() <= 2
    wide = CameraIntrinsics(CAMERA.fx, CAMERA.fy, CAMERA.cx, CAMERA.cy, 2 * CAMERA.width,
                            CAMERA.height)
    whole = render_silhouette(wide, model.vertices, model.faces, rotation, translation)
    assert whole.sum() > reference.sum() + 1000
    assert abs(result.full_pixel_counts[0] - whole.sum()) <= 4


def test_shared_depth_buffer_and_instance_ids(renderer, lmo_models):
    rotation = Rotation.from_euler('xyz', [90, 0, 30], degrees=True).as_matrix()
    far = Draw('driller', rotation, np.array([0.0, 0.0, 0.9]))
    near = Draw('ape', rotation.T, np.array([0.01, 0.02, 0.6]))
    result = renderer.render([far, near], Lighting((0.3, -0.5, -1.0), 0.3, 0.7), [0, 1])
    depths = np.stack([render_depth(CAMERA, lmo_models[d.mesh].vertices,
                                    lmo_models[d.mesh].faces, d.rotation, d.translation)
                       for d in (far, near)])
    expected = np.where(np.isfinite(depths.min(axis=0)), depths.argmin(axis=0) + 1, 0)
    assert (result.instance_ids != expected).sum() <= 4
    hidden = result.full_masks[0] & (expected == 2)
    assert hidden.sum() > 100  # the ape hides part of the driller
    assert result.full_pixel_counts[0] > (result.instance_ids == 1).sum()
