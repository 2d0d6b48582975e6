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

"""The per-object pose spread behind the node's Detection3D covariance."""

import numpy as np
from scipy.spatial.transform import Rotation

from bbpose_ros.core.eval.spread import MAD_TO_SIGMA, pose_errors, spread_of
from bbpose_ros.core.pipeline.poses import Detection, PoseEstimate


def test_errors_are_per_camera_axis_and_poses_far_from_any_truth_are_left_out(lmo_frames,
                                                                              lmo_models):
    frame = lmo_frames[0]
    truth = next(i for i in frame.instances if i.object_name == 'ape')
    detection = Detection('ape', 1.0, truth.box_uv)
    turn = Rotation.from_rotvec([0.0, 0.0, 0.05]).as_matrix()
    moved = PoseEstimate(detection, turn @ truth.rotation, truth.translation + [0, 0, 0.01])
    t_err, r_err = pose_errors(moved, frame.instances, lmo_models)
    np.testing.assert_allclose(t_err, [0.0, 0.0, 0.01], atol=1e-9)
    np.testing.assert_allclose(r_err, [0.0, 0.0, 0.05], atol=1e-6)
    far = PoseEstimate(detection, truth.rotation, truth.translation + [0, 0, 1.0])
    assert pose_errors(far, frame.instances, lmo_models) is None


def test_the_spread_is_the_scaled_median_absolute_error():
    rows = [(np.array([x, 0.0, 2 * x]), np.zeros(3), c)
            for x, c in [(-0.01, 0.5), (0.02, 0.7), (0.03, 0.9)]]
    spread = spread_of(rows)
    np.testing.assert_allclose(spread['sigma_m'], [MAD_TO_SIGMA * 0.02, 0.0,
                                                   MAD_TO_SIGMA * 0.04], atol=1e-5)
    assert spread['confidence_median'] == 0.7 and spread['n'] == 3
