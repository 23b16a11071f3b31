"""imu_complementary_filter's launch file, on ccf_ros: the ccf filter as ``complementary_filter_node`` named
``complementary_filter_gain_node``.

    ros2 launch ccf_ros complementary_filter.launch.py params_file:=/path/to/filter_config.yaml

``params_file`` is an imu_complementary_filter parameters file (keyed ``complementary_filter_gain_node:``, QoS
overrides included), used unchanged; without one the node runs with imu_complementary_filter's defaults.
"""

from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription


# Standalone on purpose, like the imu_tools launch file it replaces (ros2 launch reads it by path, a user copies
# it): the two drop-ins' launch files differ only in executable, node name and the parameters file's wording.
def _node(context):
    params = LaunchConfiguration('params_file').perform(context)
    return [Node(
        package='ccf_ros',
        executable='complementary_filter_node',
        name='complementary_filter_gain_node',
        namespace=LaunchConfiguration('namespace'),
        output='screen',
        parameters=[params] if params else [],
    )]


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument('params_file', default_value='',
                              description='imu_complementary_filter parameters file'),
        DeclareLaunchArgument('namespace', default_value='', description='namespace of the node and its topics'),
        OpaqueFunction(function=_node),
    ])
