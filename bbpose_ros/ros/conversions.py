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
Messages <-> core types: Image, PoseStamped and MarkerArray.

Poses are x_cam = R x_model + t with t in metres in the image's optical frame; quaternions
in messages are in ROS order (x, y, z, w).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from builtin_interfaces.msg import Duration
from geometry_msgs.msg import Point, Pose, PoseStamped, Quaternion
import numpy as np
import numpy.typing as npt
from sensor_msgs.msg import Image
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from bbpose_ros.core.data.image_encoding import decode_image, encode_rgb8
from bbpose_ros.core.data.models import BOX_EDGES, ObjectModel
from bbpose_ros.core.geometry.rotations import matrix_to_quat_wxyz, wxyz_to_xyzw
from bbpose_ros.core.pipeline.overlays import object_color
from bbpose_ros.core.pipeline.poses import PoseEstimate

BOX_LINE_WIDTH_M = 0.003
LABEL_HEIGHT_M = 0.02


def image_to_rgb(image: Image, max_pixels: int | None = None) -> np.ndarray:
    """
    (H, W, 3) uint8 RGB array of a sensor_msgs/Image; InputError names a bad field.

    An image of more than ``max_pixels`` pixels is refused before it is copied.
    """
    return decode_image(image.height, image.width, image.encoding, image.step, image.data,
                        max_pixels)


def rgb_to_image(header: Header, image_rgb: npt.ArrayLike) -> Image:
    """sensor_msgs/Image (rgb8) of an (H, W, 3) uint8 array."""
    height, width, encoding, step, data = encode_rgb8(image_rgb)
    return Image(header=header, height=height, width=width, encoding=encoding,
                 is_bigendian=0, step=step, data=data.tobytes())


def poses_to_messages(poses: Sequence[PoseEstimate]) -> list[Pose]:
    """
    Make the geometry_msgs/Pose of each PoseEstimate of a frame (metres, ROS (x, y, z, w)).

    All rotations go to quaternions in one batched call, which costs little more than a
    single one, and the node needs each pose twice (PoseStamped and marker).
    """
    if not poses:
        return []
    quats = _quats_xyzw(np.stack([pose.rotation for pose in poses]))
    return [_pose(q_xyzw, pose.translation) for q_xyzw, pose in zip(quats, poses)]


def frame_messages(header: Header, poses: Sequence[PoseEstimate], markers: MarkerArrayBuilder
                   ) -> tuple[list[tuple[str, PoseStamped]], MarkerArray]:
    """
    Make a frame's outputs: [(object name, PoseStamped)] and the MarkerArray of ``markers``.

    ``markers`` is a MarkerArrayBuilder; each pose's Pose message is made once and shared by
    its PoseStamped and its markers. Everything is stamped with ``header``.
    """
    pose_msgs = poses_to_messages(poses)
    stamped = [(pose.object_name, PoseStamped(header=header, pose=pose_msg))
               for pose, pose_msg in zip(poses, pose_msgs)]
    return stamped, markers(header, poses, pose_msgs)


def delete_all_markers(header: Header) -> MarkerArray:
    """
    Return the MarkerArray that clears this node's markers (one DELETEALL).

    Published when the node stops answering (deactivate, cleanup, shutdown), so the last
    frame's boxes do not stay in RViz.
    """
    return MarkerArray(markers=[Marker(header=header, action=Marker.DELETEALL)])


class MarkerArrayBuilder:
    """
    Makes a frame's visualization_msgs/MarkerArray from its PoseEstimates.

    DELETEALL first, then per pose a LINE_LIST of the 12 edges of the object's 3D box
    (24 points in the model frame, the marker posed at the estimate) and a
    TEXT_VIEW_FACING label "name confidence" (``PoseEstimate.confidence``); ns is the object
    name, ids count the instances of that object (box 2k, label 2k + 1), the colour is
    fixed per object. The points and
    colours of each object are made once, here.

    Args:
        models: {object name: ObjectModel}.

    """

    def __init__(self, models: Mapping[str, ObjectModel]) -> None:
        self._points = {name: [Point(x=float(x), y=float(y), z=float(z))
                               for x, y, z in model.box_corners[BOX_EDGES.reshape(-1)]]
                        for name, model in models.items()}
        self._colors = {name: _color(model.obj_id) for name, model in models.items()}

    def __call__(self, header: Header, poses: Sequence[PoseEstimate],
                 pose_msgs: Sequence[Pose] | None = None,
                 labels: Sequence[str] | None = None) -> MarkerArray:
        """
        Return the MarkerArray of a frame's poses, stamped with its header.

        ``pose_msgs``: the poses' geometry_msgs/Pose if already made (``poses_to_messages``);
        ``labels``: the label of each pose (default "name confidence").
        """
        if labels is None:
            labels = [f'{pose.object_name} {pose.confidence:.2f}' for pose in poses]
        markers = [Marker(header=header, action=Marker.DELETEALL)]
        instance = {}
        if pose_msgs is None:
            pose_msgs = poses_to_messages(poses)
        for pose, pose_msg, text in zip(poses, pose_msgs, labels):
            name = pose.object_name
            k = instance[name] = instance.get(name, -1) + 1
            common = {'header': header, 'ns': name, 'action': Marker.ADD, 'pose': pose_msg,
                      'color': self._colors[name], 'lifetime': Duration()}
            box = Marker(id=2 * k, type=Marker.LINE_LIST, points=self._points[name], **common)
            box.scale.x = BOX_LINE_WIDTH_M
            label = Marker(id=2 * k + 1, type=Marker.TEXT_VIEW_FACING,
                           text=text, **common)
            label.scale.z = LABEL_HEIGHT_M
            markers += [box, label]
        return MarkerArray(markers=markers)


def _color(obj_id):
    r, g, b = (c / 255.0 for c in object_color(obj_id))
    return ColorRGBA(r=r, g=g, b=b, a=1.0)


def _quats_xyzw(rotations):
    """(..., 4) ROS-order quaternions of (..., 3, 3) rotation matrices."""
    return wxyz_to_xyzw(matrix_to_quat_wxyz(rotations))


def _pose(q_xyzw, translation_m):
    x, y, z, w = (float(v) for v in q_xyzw)
    tx, ty, tz = (float(v) for v in translation_m)
    return Pose(position=Point(x=tx, y=ty, z=tz), orientation=Quaternion(x=x, y=y, z=z, w=w))
