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


"""Table-top scenes: meshes resting on the table, apart, exact ground truth, LM-O cameras."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from bbpose_ros.core.eval.metrics import cm_deg_errors
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.dense_grid import model_box
from bbpose_ros.core.geometry.dense_pnp import pose_from_dense_maps
from bbpose_ros.core.geometry.projection import projected_box_uv
from bbpose_ros.core.render.reference import render_depth
from bbpose_ros.core.synth.camera_path import orbit_path
from bbpose_ros.core.synth.effects import color_response
from bbpose_ros.core.synth.stable_poses import compute_stable_poses, resting_height
from bbpose_ros.core.synth.table_config import TableConfig
from bbpose_ros.core.synth.table_crops import TableCrops
from bbpose_ros.core.synth.table_layout import look_at, polygons_overlap
from bbpose_ros.core.synth.table_scenes import TableScenes
from bbpose_ros.core.training.crop_cache import build_crop_cache, CropCache
from bbpose_ros.core.util.errors import InputError

pytestmark = pytest.mark.slow   # renders with OpenGL

CAMERA = CameraIntrinsics(572.4114, 573.57043, 325.2611, 242.04899, 640, 480)
TARGETS = ('ape', 'duck', 'glue')
# Few meshes keep the reference z-buffer and the stable poses quick.
CONFIG = TableConfig(targets_per_image=(3, 3), clutter_per_image=(4, 5), shape_count=4)


@pytest.fixture(scope='module')
def table(lmo_models):
    """Table scenes of TARGETS among the can and random shapes, seed 5."""
    scenes = TableScenes({name: lmo_models[name] for name in TARGETS}, CAMERA, 5, CONFIG,
                         {'can': lmo_models['can']})
    try:
        scenes.sample(0)
    except RuntimeError as err:
        pytest.skip(f'headless OpenGL (EGL) unavailable: {err}')
    yield scenes
    scenes.close()


@pytest.fixture(scope='module')
def rendered(table):
    """Render samples 0-2 with their layouts."""
    return [table.sample_with_layout(i) for i in range(3)]


def _world_points(table, placed):
    return table.renderer.meshes[placed.key].vertices.astype(float) @ placed.rotation.T + \
        placed.translation


def test_meshes_rest_on_the_table_and_do_not_intersect(table, rendered):
    for _, layout in rendered:
        assert len(layout.meshes) >= 6
        points = [_world_points(table, placed) for placed in layout.meshes]
        for cloud in points:
            assert abs(cloud[:, 2].min()) < 1e-5         # resting on the table (metres)
        # No vertex of one mesh lies more than 1 mm inside another's convex hull.
        for a, cloud in enumerate(points):
            hull = ConvexHull(cloud)
            for b, other in enumerate(points):
                if a != b:
                    inside = other @ hull.equations[:, :3].T + hull.equations[:, 3]
                    assert inside.max(axis=1).min() > -0.001


def test_ground_truth_matches_a_reference_z_buffer(table, rendered, lmo_models):
    checked = 0
    for sample, layout in rendered[:2]:
        rotation_wc, translation_wc = layout.world_to_camera[:3, :3], \
            layout.world_to_camera[:3, 3]
        depths = []
        for placed in layout.meshes:
            mesh = table.renderer.meshes[placed.key]
            depths.append(render_depth(CAMERA, mesh.vertices, mesh.faces,
                                       rotation_wc @ placed.rotation,
                                       rotation_wc @ placed.translation + translation_wc))
        depths = np.stack(depths)
        front = np.where(np.isfinite(depths.min(axis=0)), depths.argmin(axis=0), -1)
        keys = [placed.key for placed in layout.meshes]
        masks = np.stack([instance.mask for instance in sample.instances])
        assert masks.sum(axis=0).max() <= 1
        for instance in sample.instances:
            model = lmo_models[instance.object_name]
            np.testing.assert_allclose(instance.box_uv, projected_box_uv(
                CAMERA, model.vertices, instance.rotation, instance.translation), atol=1e-6)
            k = keys.index(f'target/{instance.object_name}')
            visible = front == k
            # Edge pixels may differ between the rasterisers.
            assert np.count_nonzero(visible ^ instance.mask) <= 0.02 * visible.sum() + 30
            box = instance.box_uv
            if box[0] >= 0 and box[1] >= 0 and box[2] <= 639 and box[3] <= 479:
                full = np.isfinite(depths[k])
                assert instance.visib_fract == pytest.approx(
                    instance.mask.sum() / full.sum(), abs=0.02)
                checked += 1
    assert checked >= 3


def test_cameras_look_down_at_the_table_as_configured(rendered):
    for _, layout in rendered:
        rotation_wc = layout.world_to_camera[:3, :3]
        position = -rotation_wc.T @ layout.world_to_camera[:3, 3]
        distance = np.linalg.norm(position)
        low, high = CONFIG.camera_distance_range
        assert low - 0.25 < distance < high + 0.25       # from the look point, near the origin
        elevation = np.degrees(np.arcsin(position[2] / distance))
        assert CONFIG.camera_elevation_range_deg[0] - 15 < elevation < \
            CONFIG.camera_elevation_range_deg[1] + 15
        up = rotation_wc @ [0.0, 0.0, 1.0]           # the table normal, camera frame
        roll = np.degrees(np.arctan2(up[0], -up[1]))
        assert CONFIG.inplane_range_deg[0] - 1e-6 <= roll <= CONFIG.inplane_range_deg[1] + 1e-6


def test_samples_are_deterministic(table, rendered):
    again, _ = table.sample_with_layout(1)
    first, _ = rendered[1]
    np.testing.assert_array_equal(again.image_rgb, first.image_rgb)
    assert [i.object_name for i in again.instances] == [i.object_name for i in first.instances]


def test_table_crops_carry_the_scenes_ground_truth_and_exact_dense_targets(
        lmo_models, rendered, tmp_path):
    source = TableCrops({name: lmo_models[name] for name in TARGETS}, CAMERA, 5, CONFIG,
                        {'can': lmo_models['can']}, crop_size=96, dense_size=16)
    count = 0
    for index in range(2):
        crops = source.crops(index)
        count += len(crops)
        sample, _ = rendered[index]
        instances = {i.object_name: i for i in sample.instances if i.visib_fract >= 0.15}
        assert sorted(c.object_name for c in crops) == sorted(instances)
        for crop in crops:
            instance = instances[crop.object_name]
            np.testing.assert_array_equal(crop.rotation, instance.rotation)
            assert crop.image_rgb.shape == (96, 96, 3) and crop.coordinates.shape == (16, 16, 3)
            assert np.all(crop.visible_mask <= crop.amodal_mask + 1e-6)
            # The unlit coordinate pass sees what the lit frame showed: the visible share
            # of the crop's cells adds up to the instance's visible pixels.
            cell_area = ((crop.square_uv[2] - crop.square_uv[0]) / 16) ** 2
            visible_px = crop.visible_mask.sum() * cell_area
            assert abs(visible_px - instance.mask.sum()) < 0.1 * instance.mask.sum() + 40
            full = crop.visible_mask > 0.99
            if full.sum() < 8:
                continue
            model = lmo_models[crop.object_name]
            pose = pose_from_dense_maps(crop.coordinates, full.astype(float), crop.square_uv,
                                        CAMERA, *model_box(model.vertices))
            re_deg, te_m = cm_deg_errors(pose.rotation, pose.translation, crop.rotation,
                                         crop.translation, model.symmetry_transforms)
            assert re_deg < 1.0 and te_m < 0.003, (crop.object_name, re_deg, te_m)
    # A cache of table crops: shards of scenes, each holding their crops.
    build_crop_cache(source, tmp_path / 'table', 2, workers=1, progress=False, shard_size=1)
    source.close()
    cache = CropCache(tmp_path / 'table')
    assert cache.shards == 2 and cache.dense_size == 16
    assert len(cache.visib) == count
    assert '"scene_style": "table"' in (tmp_path / 'table' / 'meta.json').read_text()


def test_stable_poses_stand_on_a_face_over_the_centre_of_mass(lmo_models):
    model = lmo_models['glue']
    poses = compute_stable_poses(model.vertices, model.faces)
    assert poses.probabilities.sum() == pytest.approx(1.0) and len(poses.probabilities) >= 2
    import trimesh
    center = trimesh.Trimesh(model.vertices, model.faces).center_mass
    for rotation in poses.rotations:
        np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-9)
        points = model.hull_points @ rotation.T
        points[:, 2] += resting_height(rotation, model.hull_points)
        contact = points[points[:, 2] < 1e-4, :2]
        assert len(contact) >= 3
        support = ConvexHull(contact)
        com = rotation @ center
        assert (support.equations[:, :2] @ com[:2] + support.equations[:, 2]).max() < 0


def test_overlap_test_separates_convex_polygons():
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    assert polygons_overlap(square, square + [0.5, 0.5])
    assert not polygons_overlap(square, square + [1.01, 0.0])
    assert polygons_overlap(square, square + [1.01, 0.0], gap=0.02)
    diamond = np.array([[0, -1], [1, 0], [0, 1], [-1, 0]], float) * 0.6 + [1.75, 1.75]
    assert not polygons_overlap(square, diamond)      # apart along the diamond's edge normal


def test_color_response_casts_a_colour_and_bends_the_mid_tones():
    image = np.full((4, 4, 3), 128, np.uint8)
    rng = np.random.default_rng(0)
    np.testing.assert_array_equal(color_response(rng, image, (1.0, 1.0), (1.0, 1.0)), image)
    darker = color_response(rng, image, (1.0, 1.0), (1.5, 1.5))
    assert (darker == round(255 * (128 / 255) ** 1.5)).all()
    cast = color_response(rng, image, (0.8, 1.2), (1.0, 1.0))
    assert len(np.unique(cast.reshape(-1, 3), axis=0)) == 1 and np.ptp(cast[0, 0]) > 5


def test_mesh_brightness_scales_the_colours_and_keeps_the_layout(rendered, lmo_models):
    _, layout = rendered[0]
    gains = np.array([draw.color_gain for draw in layout.draws])
    assert np.all((gains >= CONFIG.color_gain_range[0]) & (gains <= CONFIG.color_gain_range[1]))
    # Brightness 2 without per-channel spread: every mesh's colours exactly doubled; the
    # layout and the camera are drawn before the colours, so they stay.
    config = replace(CONFIG, brightness_range=(2.0, 2.0), color_gain_range=(1.0, 1.0))
    bright = TableScenes({name: lmo_models[name] for name in TARGETS}, CAMERA, 5, config,
                         {'can': lmo_models['can']})
    try:
        _, doubled = bright.sample_with_layout(0)
    finally:
        bright.close()
    assert [tuple(draw.color_gain) for draw in doubled.draws] == \
        [pytest.approx((2.0, 2.0, 2.0))] * len(layout.draws)
    assert [mesh.key for mesh in doubled.meshes] == [mesh.key for mesh in layout.meshes]
    np.testing.assert_array_equal(doubled.world_to_camera, layout.world_to_camera)


def _first_sample(lmo_models, config):
    """Render sample 0 of the ``table`` fixture's scenes under another ``config``."""
    scenes = TableScenes({name: lmo_models[name] for name in TARGETS}, CAMERA, 5, config,
                         {'can': lmo_models['can']})
    try:
        return scenes.sample_with_layout(0)
    finally:
        scenes.close()


def test_scenes_without_shadows_keep_the_layout_and_ground_truth(rendered, lmo_models):
    sample, layout = rendered[0]
    flat, flat_layout = _first_sample(lmo_models, replace(CONFIG, shadows=False))
    # Shadows draw nothing from the random stream: the same scene, ground truth and camera
    # effects; only the light differs, and taking shadows away only brightens it.
    assert [mesh.key for mesh in flat_layout.meshes] == [mesh.key for mesh in layout.meshes]
    np.testing.assert_array_equal(flat_layout.world_to_camera, layout.world_to_camera)
    assert len(flat.instances) == len(sample.instances)
    for mine, theirs in zip(flat.instances, sample.instances):
        assert mine.object_name == theirs.object_name
        assert mine.visib_fract == theirs.visib_fract
        np.testing.assert_array_equal(mine.box_uv, theirs.box_uv)
        np.testing.assert_array_equal(mine.mask, theirs.mask)
    gain = flat.image_rgb.astype(int) - sample.image_rgb.astype(int)
    assert gain.mean() > 0.5
    assert np.mean(gain > 10) > 20 * np.mean(gain < -10)


def test_scenes_without_clutter_keep_the_targets_and_the_room(rendered, lmo_models):
    sample, layout = rendered[0]
    bare, bare_layout = _first_sample(lmo_models, replace(CONFIG, clutter=False))
    # The clutter is drawn, then left out: the same targets, poses and camera, the same
    # amodal boxes, each target at least as visible as among the clutter.
    targets = [mesh for mesh in layout.meshes if mesh.key.startswith('target/')]
    assert len(targets) < len(layout.meshes)
    assert [mesh.key for mesh in bare_layout.meshes] == [mesh.key for mesh in targets]
    for mine, theirs in zip(bare_layout.meshes, targets):
        np.testing.assert_array_equal(mine.translation, theirs.translation)
    np.testing.assert_array_equal(bare_layout.world_to_camera, layout.world_to_camera)
    cluttered = {instance.object_name: instance for instance in sample.instances}
    assert set(cluttered) <= {instance.object_name for instance in bare.instances}
    for instance in bare.instances:
        if instance.object_name in cluttered:
            theirs = cluttered[instance.object_name]
            np.testing.assert_allclose(instance.box_uv, theirs.box_uv)
            assert instance.visib_fract >= theirs.visib_fract - 1e-6
    # The room is drawn from the same stream: most pixels are unchanged or nearly so.
    change = np.abs(bare.image_rgb.astype(int) - sample.image_rgb.astype(int)).max(axis=2)
    assert 0.05 < np.mean(change > 20) < 0.6


def test_default_colours_draw_only_the_channel_gains(table):
    # Without a brightness range the colours take three draws, as before the option existed,
    # so the default renders the seeds' scenes unchanged.
    rng, plain = np.random.default_rng(3), np.random.default_rng(3)
    assert table._color_gains(rng) == tuple(plain.uniform(*CONFIG.color_gain_range, 3))
    assert rng.random() == plain.random()


def test_bad_config_is_refused(lmo_models):
    with pytest.raises(InputError, match='lights_per_image'):
        TableConfig(lights_per_image=(1, 4))
    with pytest.raises(InputError, match='brightness_range must be > 0'):
        TableConfig(brightness_range=(0.0, 2.0))
    with pytest.raises(InputError, match='color_gain_range must be >= 0'):
        TableConfig(color_gain_range=(-0.1, 1.0))
    with pytest.raises(InputError, match='brightness_range must be finite'):
        TableConfig(brightness_range=(1.0, float('inf')))
    with pytest.raises(InputError, match='camera_elevation'):
        replace(CONFIG, camera_elevation_range_deg=(10.0, 95.0))
    with pytest.raises(InputError, match='both targets and distractors'):
        TableScenes({'ape': lmo_models['ape']}, CAMERA, 0, CONFIG, {'ape': lmo_models['ape']})


def test_a_camera_path_sees_one_scene_from_moving_poses(table, rendered):
    samples = [table.sample_with_layout(0, pose)
               for pose in orbit_path(table.camera_pose(0), 4, 5.0, 20.0, bob_m=0.02)]
    # At t = 0 the path is the sample's own camera: the same objects at the same poses.
    for mine, theirs in zip(samples[0][0].instances, rendered[0][0].instances):
        assert mine.object_name == theirs.object_name
        np.testing.assert_allclose(mine.rotation, theirs.rotation, atol=1e-12)
        np.testing.assert_allclose(mine.translation, theirs.translation, atol=1e-12)
    assert len(samples[0][0].instances) == len(rendered[0][0].instances)
    assert not np.array_equal(samples[3][0].image_rgb, samples[0][0].image_rgb)
    # Seen again from a pose of the path, the scene renders the same: one random stream.
    again = table.sample_with_layout(0, samples[2][1].world_to_camera)[0]
    assert np.array_equal(again.image_rgb, samples[2][0].image_rgb)
    first, first_layout = samples[0]
    for sample, layout in samples[1:]:
        assert [m.key for m in layout.meshes] == [m.key for m in first_layout.meshes]
        # The objects stay where they were on the table: model-to-world is the same.
        theirs = {i.object_name: i for i in first.instances}
        assert {i.object_name for i in sample.instances} & set(theirs)
        for mine in sample.instances:
            if mine.object_name not in theirs:
                continue
            world = [np.linalg.inv(pose) for pose in (layout.world_to_camera,
                                                      first_layout.world_to_camera)]
            other = theirs[mine.object_name]
            np.testing.assert_allclose(world[0][:3, :3] @ mine.rotation,
                                       world[1][:3, :3] @ other.rotation, atol=1e-9)
            np.testing.assert_allclose(world[0][:3, :3] @ mine.translation + world[0][:3, 3],
                                       world[1][:3, :3] @ other.translation + world[1][:3, 3],
                                       atol=1e-9)


def test_an_orbit_turns_about_the_point_looked_at():
    start = look_at(np.array([0.3, 0.0, 0.5]), np.array([0.05, 0.02, 0.0]), 0.2)
    poses = orbit_path(start, 31, 30.0, 30.0)
    for pose in poses:
        # The point looked at on the table stays on the optical axis, at the same depth.
        target = pose[:3, :3] @ np.array([0.05, 0.02, 0.0]) + pose[:3, 3]
        np.testing.assert_allclose(target[:2], 0.0, atol=1e-9)
        assert target[2] == pytest.approx(np.linalg.norm([0.25, -0.02, 0.5]))
    centres = [-pose[:3, :3].T @ pose[:3, 3] for pose in poses]
    turned = np.degrees(np.arctan2(centres[-1][1] - 0.02, centres[-1][0] - 0.05)
                        - np.arctan2(centres[0][1] - 0.02, centres[0][0] - 0.05))
    assert turned == pytest.approx(30.0)        # 1 s at 30 deg/s
    with pytest.raises(InputError, match='looking down'):
        orbit_path(look_at(np.array([0.3, 0.0, -0.5]), np.zeros(3), 0.0), 2, 30.0, 10.0)
