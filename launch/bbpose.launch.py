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
Launch bbpose_node (needs a full ROS 2 install with launch and launch_ros).

    ros2 launch bbpose_ros bbpose.launch.py params_file:=/path/to/bbpose.yaml
    ros2 launch bbpose_ros bbpose.launch.py image:=/cam/image_raw camera_info:=/cam/camera_info
    ros2 launch bbpose_ros bbpose.launch.py rviz:=true

``rviz:=true`` also starts RViz 2 (package rviz2, not a dependency of bbpose_ros) with
config/bbpose.rviz: the debug image, the pose markers and the objects' TF frames.

bbpose_node is a managed (lifecycle) node that configures and activates itself
(``autostart: true`` in the parameters file); with ``autostart: false`` a lifecycle
manager drives it through ``/bbpose_node/change_state``.

For large images between processes, export FASTRTPS_DEFAULT_PROFILES_FILE with
config/fastdds_large_images.xml in the camera driver's shell too (see that file).
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    """Start bbpose_node with a parameters file and its input topics remapped; RViz too."""
    share = get_package_share_directory('bbpose_ros')
    return LaunchDescription([
        DeclareLaunchArgument(
            'params_file', default_value=os.path.join(share, 'config', 'bbpose.yaml'),
            description='parameters of bbpose_node (see config/bbpose.yaml)'),
        DeclareLaunchArgument('image', default_value='/camera/image_raw',
                              description='sensor_msgs/Image topic'),
        DeclareLaunchArgument('camera_info', default_value='/camera/camera_info',
                              description='sensor_msgs/CameraInfo topic'),
        DeclareLaunchArgument('rviz', default_value='false',
                              description='true: start rviz2 with config/bbpose.rviz'),
        Node(package='bbpose_ros', executable='bbpose_node', name='bbpose_node',
             parameters=[LaunchConfiguration('params_file')],
             remappings=[('image', LaunchConfiguration('image')),
                         ('camera_info', LaunchConfiguration('camera_info'))],
             output='screen', emulate_tty=True),
        Node(package='rviz2', executable='rviz2', name='rviz2',
             arguments=['-d', os.path.join(share, 'config', 'bbpose.rviz')],
             condition=IfCondition(LaunchConfiguration('rviz'))),
    ])
