"""Launch ccf_node with the installed config/ccf.yaml (for real ROS 2 installs: ros2 launch ccf_ros ccf.launch.py)."""

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription


def generate_launch_description():
    params = os.path.join(get_package_share_directory('ccf_ros'), 'config', 'ccf.yaml')
    return LaunchDescription([
        DeclareLaunchArgument('params_file', default_value=params, description='ROS 2 parameters file'),
        DeclareLaunchArgument('namespace', default_value='', description='namespace of the node and its topics'),
        Node(
            package='ccf_ros',
            executable='ccf_node',
            name='ccf_node',
            namespace=LaunchConfiguration('namespace'),
            parameters=[LaunchConfiguration('params_file')],
            output='screen',
        ),
    ])
