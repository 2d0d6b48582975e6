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


"""The renderer's lit pass: same ground truth as the plain pass, cast shadows, highlights."""

from dataclasses import replace

import numpy as np
import pytest

from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.render import Draw, Lighting, MeshRenderer, RenderMesh
from bbpose_ros.core.render.scene_light import Material, PointLight, SceneLights, \
    TexturedPlane
from bbpose_ros.core.synth.table_layout import look_at

pytestmark = pytest.mark.slow   # renders with OpenGL

CAMERA = CameraIntrinsics(572.4114, 573.57043, 325.2611, 242.04899, 640, 480)
# A camera 0.7 m from the world origin, 45 deg above the table z = 0.
WORLD_TO_CAMERA = look_at(np.array([0.0, -0.5, 0.5]), np.zeros(3), 0.0)
R_WC, T_WC = WORLD_TO_CAMERA[:3, :3], WORLD_TO_CAMERA[:3, 3]


@pytest.fixture(scope='module')
def renderer(lmo_models):
    """Build a MeshRenderer of the ape and the duck; skip when EGL is unavailable."""
    renderer = MeshRenderer(CAMERA, {name: RenderMesh.from_object_model(lmo_models[name])
                                     for name in ('ape', 'duck')})
    try:
        renderer.render([], Lighting())
    except RuntimeError as err:
        pytest.skip(f'headless OpenGL (EGL) unavailable: {err}')
    yield renderer
    renderer.close()


def standing(lmo_models, name, x, y):
    """Make the draw of mesh ``name`` standing upright on the table at (x, y) metres."""
    lift = -lmo_models[name].vertices[:, 2].min()
    return Draw(name, R_WC.copy(), R_WC @ np.array([x, y, lift]) + T_WC)


def table():
    """Make a plain grey table under the objects."""
    return TexturedPlane(R_WC, T_WC, (1.0, 1.0), np.full((8, 8, 3), 200, np.uint8))


def lights(*positions_world):
    """Make ambient light plus grey point lights at world positions (metres)."""
    return SceneLights(tuple(PointLight(tuple(R_WC @ p + T_WC), (0.5, 0.5, 0.5))
                             for p in positions_world), (0.4, 0.4, 0.4), tuple(T_WC), 0.3)


def test_lit_pass_gives_the_plain_pass_ids_and_full_masks(renderer, lmo_models):
    draws = [standing(lmo_models, 'ape', 0.0, 0.0), standing(lmo_models, 'duck', 0.02, 0.09)]
    plain = renderer.render(draws, Lighting(), (0, 1))
    lit = renderer.render_lit(draws, lights(np.array([0.3, 0.2, 1.0])), None, (), (0, 1))
    np.testing.assert_array_equal(lit.instance_ids, plain.instance_ids)
    assert lit.full_pixel_counts == plain.full_pixel_counts
    assert 0 < np.count_nonzero(plain.instance_ids == 2) < plain.full_pixel_counts[1]
    np.testing.assert_array_equal(lit.covered, plain.instance_ids > 0)
    on_table = renderer.render_lit(draws, lights(np.array([0.3, 0.2, 1.0])), None, [table()])
    np.testing.assert_array_equal(on_table.instance_ids, plain.instance_ids)
    assert on_table.covered.mean() > 0.5                # the table fills the lower view


def test_a_light_casts_the_shadow_of_a_mesh_on_the_table(renderer, lmo_models):
    ape = [standing(lmo_models, 'ape', 0.0, 0.0)]
    light = lights(np.array([0.6, 0.0, 0.6]))           # from the right, 45 deg high
    empty = renderer.render_lit([], light, None, [table()]).rgb.astype(int)
    shaded = renderer.render_lit(ape, light, None, [table()])
    table_pixels = shaded.instance_ids == 0
    darker = table_pixels & (shaded.rgb.astype(int).sum(axis=2) < empty.sum(axis=2) - 30)
    assert darker.sum() > 300                            # a shadow ...
    cols = np.nonzero(darker)[1]
    ape_cols = np.nonzero(shaded.instance_ids == 1)[1]
    assert np.median(cols) < np.median(ape_cols)         # ... on the side away from the light
    unshadowed = replace(light, cast_shadows=False)       # the same light, no shadow
    np.testing.assert_array_equal(
        renderer.render_lit(ape, unshadowed, None, [table()]).rgb[table_pixels],
        empty[table_pixels])
    ambient = lights()                                   # no point light: no shadow
    flat = renderer.render_lit(ape, ambient, None, [table()])
    flat_empty = renderer.render_lit([], ambient, None, [table()])
    np.testing.assert_array_equal(flat.rgb[flat.instance_ids == 0],
                                  flat_empty.rgb[flat.instance_ids == 0])


def test_specular_material_adds_highlights_on_the_mesh_only(renderer, lmo_models):
    duck = [standing(lmo_models, 'duck', 0.0, 0.0)]
    light = lights(np.array([0.0, -0.4, 0.6]))           # near the camera: highlights face it
    matte = renderer.render_lit(duck, light, [Material(0.0)], [table()]).rgb.astype(int)
    glossy = renderer.render_lit(duck, light, [Material(0.8, 32.0)], [table()])
    gain = glossy.rgb.astype(int).sum(axis=2) - matte.sum(axis=2)
    assert gain[glossy.instance_ids == 1].max() > 120
    assert (gain[glossy.instance_ids == 0] == 0).all()
    assert (gain >= 0).all()
