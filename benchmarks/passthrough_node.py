"""Reference node for benchmarks: subscribe imu/data_raw (+ imu/mag, ignored) and republish on imu/data, nothing else."""

from __future__ import annotations

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Imu, MagneticField


class PassThrough(Node):
    def __init__(self) -> None:
        super().__init__('passthrough')
        self.pub = self.create_publisher(Imu, 'imu/data', 10)
        self.create_subscription(Imu, 'imu/data_raw', self.pub.publish, qos_profile_sensor_data)
        self.create_subscription(MagneticField, 'imu/mag', lambda _m: None, qos_profile_sensor_data)


def main() -> None:
    rclpy.init()
    node = PassThrough()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
