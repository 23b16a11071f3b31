"""imu_filter_madgwick's launch file, on ccf_ros: the ccf filter as ``imu_filter_madgwick_node`` named ``imu_filter``.

    ros2 launch ccf_ros imu_filter.launch.py params_file:=/path/to/imu_filter.yaml

``params_file`` is an imu_filter_madgwick parameters file (keyed ``imu_filter:``), used unchanged; without one the
node runs with imu_filter_madgwick's defaults (use_mag, publish_tf, fixed_frame odom, world_frame enu).
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
        executable='imu_filter_madgwick_node',
        name='imu_filter',
        namespace=LaunchConfiguration('namespace'),
        output='screen',
        parameters=[params] if params else [],
    )]


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument('params_file', default_value='', description='imu_filter_madgwick parameters file'),
        DeclareLaunchArgument('namespace', default_value='', description='namespace of the node and its topics'),
        OpaqueFunction(function=_node),
    ])
