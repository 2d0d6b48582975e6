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


"""The scene map: rays intersected, outliers and symmetries, moved objects, bad camera poses."""

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bbpose_ros.core.adaptation.frames import RecordedFrame
from bbpose_ros.core.adaptation.map_labels import mapped_teacher_poses
from bbpose_ros.core.adaptation.teacher import TeacherPose
from bbpose_ros.core.eval.static_stretches import camera_poses, noisy_pose, static_stretches
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.projection import projected_box_uv
from bbpose_ros.core.geometry.rigid import invert_rigid, rigid_matrix
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.pipeline.poses import Detection, PoseEstimate
from bbpose_ros.core.scene.object_map import ObjectMap
from bbpose_ros.core.util.errors import InputError

CAMERA = CameraIntrinsics(572.4, 573.6, 325.3, 242.0, 640, 480)
OBJECT_IN_WORLD = rigid_matrix(Rotation.from_euler('xyz', [10, 20, 30], degrees=True)
                               .as_matrix(), [0.0, 0.0, 0.0])


def looking_at_origin(azimuth_deg, distance=0.9, elevation_deg=40.0):
    """(4, 4) world_from_camera of a camera on a sphere around the origin, aimed at it."""
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    position = distance * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az),
                                    np.sin(el)])
    forward = -position / distance
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    return rigid_matrix(np.stack([right, down, forward], axis=1), position)


def seen_from(world_from_camera, object_in_world=OBJECT_IN_WORLD, depth_error=0.0,
              turn_deg=0.0, name='ape', score=0.9, model=None):
    """Return the object's pose in a camera, moved along its ray by ``depth_error`` (share)."""
    pose = invert_rigid(world_from_camera) @ object_in_world
    rotation = pose[:3, :3] @ Rotation.from_euler('z', turn_deg, degrees=True).as_matrix()
    translation = pose[:3, 3] * (1.0 + depth_error)
    box = np.array([0.0, 0.0, 1.0, 1.0]) if model is None else \
        projected_box_uv(CAMERA, model.hull_points, rotation, translation)
    return PoseEstimate(Detection(name, 1.0, box), rotation, translation, score)


def add(scene_map, world_from_camera, poses, view=[0]):
    view[0] += 1
    return scene_map.add_view(view[0] * 33_000_000, world_from_camera, CAMERA, poses)


def test_views_from_different_directions_fix_the_depth_no_view_has(lmo_models):
    scene_map = ObjectMap(lmo_models, PipelineOptions(map_camera_sigma_mm=0.0,
                                                      map_camera_sigma_deg=0.0))
    errors = []
    for azimuth, depth_error in ((0, 0.05), (60, -0.04), (120, 0.06)):
        camera = looking_at_origin(azimuth)
        add(scene_map, camera, [seen_from(camera, depth_error=depth_error)])
        errors.append(abs(depth_error) * 0.9)
    (ape,) = scene_map.objects()
    assert np.linalg.norm(ape.translation) < 0.2 * min(errors)
    assert ape.views == 3
    assert np.sqrt(np.linalg.eigvalsh(ape.covariance)[-1]) < 0.5 * 0.04 * 0.9


def test_a_view_disagreeing_with_the_others_is_left_out(lmo_models):
    scene_map = ObjectMap(lmo_models, PipelineOptions())
    for azimuth, turn in ((0, 0), (30, 0), (60, 90), (90, 0)):
        camera = looking_at_origin(azimuth)
        add(scene_map, camera, [seen_from(camera, turn_deg=turn)])
    (ape,) = scene_map.objects()
    assert ape.views == 3
    angle = Rotation.from_matrix(ape.rotation.T @ OBJECT_IN_WORLD[:3, :3]).magnitude()
    assert np.degrees(angle) < 0.5


def test_a_symmetric_object_fuses_its_equivalent_poses_as_one(lmo_models):
    eggbox = lmo_models['eggbox']
    symmetry = eggbox.symmetry_transforms[1]
    scene_map = ObjectMap(lmo_models, PipelineOptions())
    for azimuth, flipped in ((0, False), (40, True), (80, False), (120, True)):
        camera = looking_at_origin(azimuth)
        in_world = OBJECT_IN_WORLD @ symmetry if flipped else OBJECT_IN_WORLD
        add(scene_map, camera, [seen_from(camera, in_world, name='eggbox')])
    (entry,) = scene_map.objects()
    assert entry.views == 4
    angles = [Rotation.from_matrix(entry.rotation.T @ (OBJECT_IN_WORLD @ s)[:3, :3]).magnitude()
              for s in eggbox.symmetry_transforms]   # the file's flip is not exact
    assert np.degrees(min(angles)) < 1.0


def test_a_moved_object_starts_afresh_and_a_hidden_one_keeps_its_pose(lmo_models):
    options = PipelineOptions(map_move_views=3)
    scene_map = ObjectMap(lmo_models, options)
    moved_to = rigid_matrix(OBJECT_IN_WORLD[:3, :3], [0.15, 0.05, 0.0])
    for k in range(6):
        camera = looking_at_origin(20 * k)
        add(scene_map, camera, [seen_from(camera), seen_from(camera, name='can')])
    for k in range(3):
        camera = looking_at_origin(20 * k + 5)
        add(scene_map, camera, [seen_from(camera, moved_to), seen_from(camera, name='can')])
        ape = next(o for o in scene_map.objects() if o.object_name == 'ape')
        moved = np.linalg.norm(ape.translation - moved_to[:3, 3]) < 1e-6
        assert moved == (k == 2)
    assert ape.views == 3
    camera = looking_at_origin(100)
    stamp = add(scene_map, camera, [seen_from(camera, name='can')])
    ape = next(o for o in scene_map.objects() if o.object_name == 'ape')
    can = next(o for o in scene_map.objects() if o.object_name == 'can')
    assert np.linalg.norm(ape.translation - moved_to[:3, 3]) < 1e-6
    assert ape.last_seen_ns < can.last_seen_ns and ape.age_s(can.last_seen_ns) > 0.0
    assert stamp >= 0


def test_poses_in_view_leave_out_objects_behind_the_camera_or_outside(lmo_models):
    scene_map = ObjectMap(lmo_models, PipelineOptions())
    camera = looking_at_origin(0)
    view = add(scene_map, camera, [seen_from(camera, model=lmo_models['ape'])])
    (pose,) = scene_map.poses_in_view(camera, CAMERA, [], view)
    assert pose.source == 'map' and pose.object_name == 'ape'
    expected = invert_rigid(camera) @ OBJECT_IN_WORLD
    assert np.allclose(pose.translation, expected[:3, 3], atol=1e-9)
    away = looking_at_origin(180)
    away[:3, :3] = away[:3, :3] @ np.diag([-1.0, 1.0, -1.0])   # turned away from the object
    assert scene_map.poses_in_view(away, CAMERA) == []


@pytest.mark.parametrize('bad', [np.full((4, 4), np.nan), np.diag([2.0, 1.0, 1.0, 1.0]),
                                 np.diag([1.0, 1.0, -1.0, 1.0])])
def test_a_bad_camera_pose_is_refused_and_leaves_the_map_as_it_was(lmo_models, bad):
    scene_map = ObjectMap(lmo_models, PipelineOptions())
    camera = looking_at_origin(0)
    add(scene_map, camera, [seen_from(camera)])
    before = scene_map.objects()
    with pytest.raises(InputError, match='camera pose'):
        scene_map.add_view(1, bad, CAMERA, [seen_from(camera, depth_error=0.1)])
    (after,) = scene_map.objects()
    assert np.array_equal(after.translation, before[0].translation) and after.views == 1


def test_lmo_static_scenes_carry_their_objects_between_frames(lmo_frames, lmo_models):
    stretches = [s for s in static_stretches(lmo_frames) if len(s) >= 3]
    assert stretches and all(len({f.scene_id for f in s}) == 1 for s in stretches)
    for stretch in stretches[:4]:
        poses = camera_poses(stretch, lmo_models)
        assert np.allclose(poses[0], np.eye(4))
        first = {i.obj_id: i for i in stretch[0].instances}
        for frame, world_from_camera in zip(stretch[1:], poses[1:]):
            for instance in frame.instances:
                if instance.obj_id in first:
                    in_world = world_from_camera[:3, :3] @ instance.translation + \
                        world_from_camera[:3, 3]
                    assert np.linalg.norm(in_world - first[instance.obj_id].translation) < 0.01


def test_the_map_of_a_real_scene_fixes_depth_errors_along_each_ray(lmo_frames, lmo_models):
    stretch = max(static_stretches(lmo_frames), key=len)
    rng = np.random.default_rng(3)
    scene_map = ObjectMap(lmo_models, PipelineOptions())
    seen = []
    for frame, pose in zip(stretch, camera_poses(stretch, lmo_models)):
        pose = noisy_pose(pose, 2.0, 0.2, rng)
        poses = []
        for instance in frame.instances:
            depth = 1.0 + rng.choice([-1.0, 1.0]) * 0.04
            poses.append(PoseEstimate(Detection(instance.object_name, 1.0, instance.box_uv),
                                      instance.rotation, instance.translation * depth, 0.8))
        seen.append((frame, pose, poses, scene_map.add_view(0, pose, frame.camera, poses)))
    per_frame, mapped = [], []
    for frame, pose, poses, view in seen:
        fused = {p.object_name: p for p in scene_map.poses_in_view(pose, frame.camera, poses,
                                                                   view)}
        for instance, own in zip(frame.instances, poses):
            per_frame.append(np.linalg.norm(own.translation - instance.translation))
            mapped.append(np.linalg.norm(fused[instance.object_name].translation
                                         - instance.translation))
    assert np.median(mapped) < 0.5 * np.median(per_frame)


def test_alternatives_let_the_views_agree_on_a_rotation_none_chose(lmo_models):
    scene_map = ObjectMap(lmo_models, PipelineOptions())
    for azimuth in (0, 40, 80):
        camera = looking_at_origin(azimuth)
        right = seen_from(camera)
        wrong = seen_from(camera, turn_deg=60.0 + 2.0 * azimuth)   # wrong in its own way
        add(scene_map, camera, [dataclasses.replace(
            wrong, alternatives=((right.rotation, right.translation, 0.8),))])
    (ape,) = scene_map.objects()
    angle = Rotation.from_matrix(ape.rotation.T @ OBJECT_IN_WORLD[:3, :3]).magnitude()
    assert ape.views == 3 and np.degrees(angle) < 0.5


def test_a_pose_with_nan_is_left_out_and_the_map_goes_on(lmo_models):
    scene_map = ObjectMap(lmo_models, PipelineOptions())
    camera = looking_at_origin(0)
    bad = seen_from(camera)
    bad = dataclasses.replace(bad, rotation=np.full((3, 3), np.nan))
    add(scene_map, camera, [bad, seen_from(camera, name='can')])
    assert [o.object_name for o in scene_map.objects()] == ['can']
    other = looking_at_origin(40)
    add(scene_map, other, [seen_from(other)])
    assert sorted(o.object_name for o in scene_map.objects()) == ['ape', 'can']


def test_adapt_labels_take_the_depth_the_views_agree_on(lmo_frames, lmo_models):
    stretch = max(static_stretches(lmo_frames), key=len)
    rng = np.random.default_rng(5)
    frames, poses, truth = [], {}, {}
    for frame, pose in zip(stretch, camera_poses(stretch, lmo_models)):
        key = f'{frame.scene_id}/{frame.image_id}'
        frames.append(RecordedFrame(key, frame.camera, frame.load_image,
                                    noisy_pose(pose, 2.0, 0.2, rng), 'one'))
        poses[key] = [TeacherPose(i.object_name, 0.9, i.box_uv, i.rotation,
                                  i.translation * (1.0 + rng.choice([-1.0, 1.0]) * 0.04), 0.8,
                                  i.box_uv) for i in frame.instances]
        truth[key] = {i.object_name: i.translation for i in frame.instances}
    frames.append(RecordedFrame('lone', stretch[0].camera, stretch[0].load_image))
    poses['lone'] = poses[frames[0].key][:1]
    mapped, moved = mapped_teacher_poses(frames, poses, lmo_models, PipelineOptions())
    assert moved == sum(len(p) for key, p in poses.items() if key != 'lone')
    assert mapped['lone'][0] is poses['lone'][0]            # no camera pose: unchanged
    before = [np.linalg.norm(p.translation - truth[key][p.object_name])
              for key, found in poses.items() if key != 'lone' for p in found]
    after = [np.linalg.norm(p.translation - truth[key][p.object_name])
             for key, found in mapped.items() if key != 'lone' for p in found]
    assert np.median(after) < 0.5 * np.median(before)
    first = mapped[frames[0].key][0]
    assert np.allclose(first.box_uv, projected_box_uv(frames[0].camera,
                                                      lmo_models[first.object_name].hull_points,
                                                      first.rotation, first.translation))
