"""imu_filter_madgwick's ``imu_filter_component.launch.py``, on ccf_ros: the same filter as a plain node.

    ros2 launch ccf_ros imu_filter_component.launch.py params_file:=/path/to/imu_filter.yaml

imu_tools' file loads ``ImuFilterMadgwickRos`` into an ``rclcpp_components`` container; ccf_ros is Python, and an
rclpy node cannot be loaded into that container, so this file starts ``imu_filter_madgwick_node`` (named
``imu_filter``, as the component) as its own process, exactly as ``imu_filter.launch.py`` does. What is lost is
intra-process communication with other components of the same container; at IMU rates (a few hundred messages of
~300 bytes per second) the loopback copy costs microseconds per message (README: Composable launch files).
"""

import os

from launch.actions import IncludeLaunchDescription
from launch.launch_description_sources import PythonLaunchDescriptionSource

from launch import LaunchDescription


def generate_launch_description():
    here = os.path.dirname(os.path.abspath(__file__))
    # Its arguments (params_file, namespace) pass through: ros2 launch forwards them to the included file.
    return LaunchDescription([
        IncludeLaunchDescription(PythonLaunchDescriptionSource(os.path.join(here, 'imu_filter.launch.py'))),
    ])
