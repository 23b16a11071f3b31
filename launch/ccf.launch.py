"""Launch ccf_node with the installed config/ccf.yaml (for real ROS 2 installs: ros2 launch ccf_ros ccf.launch.py).

``lifecycle:=true`` starts ``ccf_lifecycle_node`` instead: the same node as a managed node, unconfigured until a
lifecycle manager (or ``ros2 lifecycle set /ccf_node configure`` then ``activate``) brings it up.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition, UnlessCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode, Node

from launch import LaunchDescription


def generate_launch_description():
    params = os.path.join(get_package_share_directory('ccf_ros'), 'config', 'ccf.yaml')
    common = {
        'package': 'ccf_ros',
        'name': 'ccf_node',
        'namespace': LaunchConfiguration('namespace'),
        'parameters': [LaunchConfiguration('params_file')],
        'output': 'screen',
    }
    lifecycle = LaunchConfiguration('lifecycle')
    return LaunchDescription([
        DeclareLaunchArgument('params_file', default_value=params, description='ROS 2 parameters file'),
        DeclareLaunchArgument('namespace', default_value='', description='namespace of the node and its topics'),
        DeclareLaunchArgument('lifecycle', default_value='false',
                              description='true: ccf_lifecycle_node (a managed node, starts unconfigured)'),
        Node(executable='ccf_node', condition=UnlessCondition(lifecycle), **common),
        LifecycleNode(executable='ccf_lifecycle_node', condition=IfCondition(lifecycle), **common),
    ])
