"""Helpers for tests that use rclpy: bag messages as rclpy messages, big-endian CDR."""

from __future__ import annotations

import functools
import signal
from pathlib import Path
from typing import Any

from ccf_ros.offline.bagio import open_bag


def read_inputs(bag: Path, stop_s: float) -> list[tuple[str, object]]:
    """The first ``stop_s`` seconds of IMU and magnetometer messages as rclpy messages, in bag order."""
    from sensor_msgs.msg import Imu, MagneticField

    out: list[tuple[str, object]] = []
    with open_bag(bag) as reader:
        conns = [c for c in reader.connections if c.topic in ('/imu/data_raw', '/imu/mag')]
        t0 = None
        for conn, t, raw in reader.messages(connections=conns):
            t0 = t if t0 is None else t0
            if t - t0 > stop_s * 1e9:
                break
            m = reader.deserialize(raw, conn.msgtype)
            if conn.topic == '/imu/mag':
                msg = MagneticField()
                msg.magnetic_field.x, msg.magnetic_field.y, msg.magnetic_field.z = (
                    m.magnetic_field.x, m.magnetic_field.y, m.magnetic_field.z)
            else:
                msg = Imu()
                msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = (
                    m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z)
                msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z = (
                    m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z)
                msg.orientation_covariance[0] = -1.0
            msg.header.stamp.sec = m.header.stamp.sec
            msg.header.stamp.nanosec = m.header.stamp.nanosec
            msg.header.frame_id = m.header.frame_id
            out.append((conn.topic, msg))
    return out


@functools.lru_cache(maxsize=1)
def _typestore():
    from ccf_ros.offline.bagio import typestore

    return typestore()


def big_endian_cdr(msg: object) -> bytes:
    """``msg`` (an rclpy Imu or MagneticField) serialized as big-endian CDR, as a big-endian host would send it."""
    from rclpy.serialization import serialize_message

    ts = _typestore()
    name = 'sensor_msgs/msg/Imu' if type(msg).__name__ == 'Imu' else 'sensor_msgs/msg/MagneticField'
    little = ts.deserialize_cdr(serialize_message(msg), name)
    data = bytes(ts.serialize_cdr(little, name, little_endian=False))
    assert data[:2] == b'\x00\x00'  # CDR_BE
    return data


def stop_node(proc: Any, harness: Any, sig: int = signal.SIGINT) -> str:
    """Stop a node process with ``sig`` and close the test harness; the node must exit cleanly (code 0, no
    traceback). Returns its output."""
    proc.send_signal(sig)
    try:
        out, _ = proc.communicate(timeout=20)
    finally:
        harness.close()
    assert proc.returncode == 0, out
    assert 'Traceback' not in out
    return str(out)
