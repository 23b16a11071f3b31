"""Reference node for benchmarks: subscribe imu/data_raw (+ imu/mag, ignored) and republish on imu/data, nothing else.

The plain rclpy way (messages deserialized, the Imu serialized again), with exactly ccf_node's QoS: the same input
profile (``qos_reliability`` best_effort, ``qos_depth`` 50, sensor-data durability, built by the same function)
and the same output depth.
"""

from __future__ import annotations

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from sensor_msgs.msg import Imu, MagneticField

from ccf_ros.node import OUTPUT_DEPTH, input_qos
from ccf_ros.node.entry import stop_signal_thread
from ccf_ros.settings import all_defaults


class PassThrough(Node):
    def __init__(self) -> None:
        super().__init__('passthrough')
        defaults = all_defaults()
        qos = input_qos(str(defaults['qos_reliability']), int(defaults['qos_depth']))
        self.pub = self.create_publisher(Imu, 'imu/data', OUTPUT_DEPTH)
        # Creation order as in ccf_node: magnetometer first.
        self.create_subscription(MagneticField, 'imu/mag', lambda _m: None, qos)
        self.create_subscription(Imu, 'imu/data_raw', self.pub.publish, qos)


def main() -> None:
    rclpy.init()
    node = PassThrough()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        stop_signal_thread()  # (as ccf_node: rclpy's signal thread must not trigger the spin's freed guard condition)
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
