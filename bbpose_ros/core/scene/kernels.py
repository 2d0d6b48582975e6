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
The map's numba kernels (``consensus``, ``views``) compiled ahead of the first mapped frame.

numba compiles them once per machine and source (tens of seconds) into its cache and loads
them from there after that (a fraction of a second). Without this, a node's first frame
with ``fixed_frame`` would hold its worker for the compilation; ``make setup`` and the
node's configure run it instead.
"""

import numpy as np
from scipy.spatial.transform import Rotation

from bbpose_ros.core.data.models import ObjectModel
from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.projection import projected_box_uv
from bbpose_ros.core.geometry.rigid import invert_rigid, rigid_matrix
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.pipeline.poses import Detection, PoseEstimate
from bbpose_ros.core.scene.object_map import FRAME_PERIOD_NS, ObjectMap


def compile_kernels() -> None:
    """
    Compile (or load) the map's kernels with the argument types a real map passes them.

    Three views of a synthetic 6 cm cube at the world's origin, from 0.8 m, one with a
    second candidate, go through ``ObjectMap.add_view``, ``objects`` and ``poses_in_view``.
    """
    half = 0.03
    corners = np.array([[x, y, z] for x in (-half, half) for y in (-half, half)
                        for z in (-half, half)])
    cube = ObjectModel('cube', 1, corners, np.zeros((0, 3), np.int64),
                       np.zeros((8, 3), np.uint8), float(np.linalg.norm(2 * corners[0])),
                       corners, corners)
    camera = CameraIntrinsics(572.4, 573.6, 325.3, 242.0, 640, 480)
    scene_map = ObjectMap({'cube': cube}, PipelineOptions())
    translation = np.array([0.0, 0.0, 0.8])
    for view, angle in enumerate((0.0, 30.0, 60.0)):
        rotation = Rotation.from_euler('xz', [120.0, angle], degrees=True).as_matrix()
        box = projected_box_uv(camera, cube.hull_points, rotation, translation)
        second = (rotation @ Rotation.from_euler('z', 90, degrees=True).as_matrix(),
                  translation, 0.5)
        pose = PoseEstimate(Detection('cube', 0.9, box), rotation, translation, 0.9,
                            alternatives=(second,) if view == 0 else ())
        world_from_camera = invert_rigid(rigid_matrix(rotation, translation))
        index = scene_map.add_view(view * FRAME_PERIOD_NS, world_from_camera, camera, [pose])
    scene_map.objects()
    scene_map.poses_in_view(world_from_camera, camera, [pose], index)
