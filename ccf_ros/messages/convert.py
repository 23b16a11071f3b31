"""Rules for message fields that every reader and writer of IMU messages shares, each written once.

No ROS or rosbags import: the node, the offline tools and the fast CDR path all use these.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from ..frames import rotate_covariance

if TYPE_CHECKING:
    from ..engine import Output


def seconds(sec: int, nanosec: int) -> float:
    """A ``builtin_interfaces/Time`` (``sec``, ``nanosec``) as float seconds.

    The one stamp rule: the same stamp gives the same float wherever it is read (node, replay, bag readers).
    Written out in :func:`~ccf_ros.messages.cdr.read_imu`, ``read_mag`` and ``FastCdrPath.read_imu`` (a call per
    message costs): those copies change together with this function.
    """
    return sec + nanosec * 1e-9


def stamp_s(header: Any) -> float:
    """A ``std_msgs/Header``'s stamp as float seconds (see :func:`seconds`)."""
    stamp = header.stamp
    return seconds(stamp.sec, stamp.nanosec)


def fill_imu(msg: Any, out: Output, covariance: Any) -> None:
    """Write the engine's answer ``out`` into an Imu message ``msg`` in place.

    Orientation and ``covariance`` (the 9 values of ``out.covariance`` in the container the message type takes);
    angular velocity and linear acceleration only where the engine gives them (None: the input's are kept).
    The message-level counterpart of :func:`~ccf_ros.messages.cdr.patch_imu` and ``patch_imu_vectors``.
    """
    o = msg.orientation
    o.x, o.y, o.z, o.w = out.orientation_xyzw
    msg.orientation_covariance = covariance
    if out.angular_velocity is not None:
        v = msg.angular_velocity
        v.x, v.y, v.z = out.angular_velocity
    if out.linear_acceleration is not None:
        v = msg.linear_acceleration
        v.x, v.y, v.z = out.linear_acceleration


def reframe_msg(msg: Any, frame_id: str, rot: Sequence[float] | None) -> None:
    """An Imu message into the output frame in place: header.frame_id ``frame_id`` (empty: kept) and the
    angular_velocity and linear_acceleration covariances turned by ``rot`` (row-major 3x3; None: kept). The
    message-level counterpart of :func:`~ccf_ros.messages.cdr.reframe_imu`."""
    if frame_id:
        msg.header.frame_id = frame_id
    if rot is not None:
        for name in ('angular_velocity_covariance', 'linear_acceleration_covariance'):
            values = rotate_covariance(rot, [float(v) for v in getattr(msg, name)])
            current = getattr(msg, name)
            flags = getattr(current, 'flags', None)
            if flags is not None and not flags.writeable:  # rosbags' ROS 1 arrays are views of the read buffer
                setattr(msg, name, current.copy())
            try:
                getattr(msg, name)[:] = values  # numpy (rosbags)
            except TypeError:
                setattr(msg, name, values)  # rclpy's array.array: its setter takes a sequence
