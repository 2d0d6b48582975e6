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


"""The TF buffer against tf2's semantics: chains, static and dynamic, interpolation, refusals."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bbpose_ros.core.geometry.rigid import invert_rigid
from bbpose_ros.core.scene.transform_buffer import TransformBuffer, TransformUnavailable
from bbpose_ros.core.util.errors import InputError

S = 1_000_000_000


def quat(axis, degrees):
    return Rotation.from_euler(axis, degrees, degrees=True).as_quat()    # (x, y, z, w)


@pytest.fixture
def arm():
    """Return a buffer of world -> base (static) -> tool (moving, turning) -> camera (static)."""
    buffer = TransformBuffer(cache_s=10.0)
    buffer.set_transform('world', 'base', 0, [1.0, 0.0, 0.0], quat('z', 90), static=True)
    for k in range(5):
        buffer.set_transform('base', 'tool', k * S, [0.0, 0.0, 0.1 * k], quat('z', 10 * k))
    buffer.set_transform('tool', 'camera', 0, [0.0, 0.05, 0.0], quat('x', 180), static=True)
    return buffer


def test_a_chain_composes_its_links_at_a_sample(arm):
    world_from_camera = arm.lookup('world', 'camera', 2 * S)
    base = Rotation.from_euler('z', 90, degrees=True)
    tool = Rotation.from_euler('z', 20, degrees=True)
    camera_origin = base.apply(tool.apply([0.0, 0.05, 0.0]) + [0.0, 0.0, 0.2]) + [1.0, 0, 0]
    assert np.allclose(world_from_camera[:3, 3], camera_origin)
    expected = (base * tool * Rotation.from_euler('x', 180, degrees=True)).as_matrix()
    assert np.allclose(world_from_camera[:3, :3], expected)
    assert np.allclose(arm.lookup('camera', 'world', 2 * S), invert_rigid(world_from_camera))


def test_between_samples_translation_is_linear_and_rotation_slerped(arm):
    base_from_tool = arm.lookup('base', 'tool', int(2.5 * S))
    assert np.allclose(base_from_tool[:3, 3], [0.0, 0.0, 0.25])
    assert np.allclose(base_from_tool[:3, :3],
                       Rotation.from_euler('z', 25, degrees=True).as_matrix())


def test_no_extrapolation_and_time_zero_is_the_latest_common_time(arm):
    with pytest.raises(TransformUnavailable, match='future'):
        arm.lookup('world', 'camera', 5 * S)
    with pytest.raises(TransformUnavailable, match='past'):
        arm.lookup('world', 'camera', -1)
    assert np.allclose(arm.lookup('world', 'camera', 0), arm.lookup('world', 'camera', 4 * S))


def test_unknown_and_unconnected_frames_are_named(arm):
    with pytest.raises(TransformUnavailable, match="'nowhere'"):
        arm.lookup('world', 'nowhere', 0)
    arm.set_transform('map', 'odom', 0, [0, 0, 0], [0, 0, 0, 1], static=True)
    with pytest.raises(TransformUnavailable, match='not connected'):
        arm.lookup('world', 'odom', 0)


@pytest.mark.parametrize('parent, child, translation, rotation, message', [
    ('base', 'tool', [np.nan, 0, 0], [0, 0, 0, 1], 'not finite'),
    ('base', 'tool', [0, 0, 0], [0, 0, 0, 2], 'quaternion'),
    ('base', 'tool', [0, 0, 0], [0, 0, 0, 0], 'quaternion'),
    ('/base', 'tool', [0, 0, 0], [0, 0, 0, 1], 'start with /'),
    ('tool', 'tool', [0, 0, 0], [0, 0, 0, 1], 'own parent'),
    ('world', 'tool', [0, 0, 0], [0, 0, 0, 1], 'already has the parent'),
])
def test_bad_transforms_are_refused_and_change_nothing(arm, parent, child, translation,
                                                       rotation, message):
    before = arm.lookup('world', 'camera', 3 * S)
    with pytest.raises(InputError, match=message):
        arm.set_transform(parent, child, 3 * S, translation, rotation)
    assert np.array_equal(arm.lookup('world', 'camera', 3 * S), before)


def test_a_slightly_off_quaternion_is_normalised(arm):
    arm.set_transform('base', 'tool', 5 * S, [0, 0, 0.5], quat('z', 50) * 1.004)
    assert np.allclose(np.linalg.det(arm.lookup('base', 'tool', 5 * S)[:3, :3]), 1.0)


def test_old_samples_leave_the_cache_and_a_clock_going_back_clears_it(arm):
    arm.set_transform('base', 'tool', 12 * S, [0, 0, 1.2], quat('z', 0))
    with pytest.raises(TransformUnavailable, match='past'):
        arm.lookup('base', 'tool', S)               # older than 10 s behind the newest
    assert arm.set_transform('base', 'tool', S, [0, 0, 0.3], quat('z', 0)) is True
    assert np.allclose(arm.lookup('base', 'tool', 0)[:3, 3], [0, 0, 0.3])
    assert np.allclose(arm.lookup('world', 'base', 0)[:3, 3], [1.0, 0, 0])   # static kept
