"""The two ways an IMU or magnetometer message goes through the node and ``ccf replay``: one protocol
(:class:`Path`), two classes. No ROS or rosbags import.

:class:`FastCdrPath` reads the few fields needed from little-endian CDR bytes and patches the answer into a copy of
them (no deserialisation); :class:`MessagePath` works on a deserialized message (big-endian CDR, ROS 1), with its
caller's deserializers and Vector3Stamped maker (rclpy's in the node, rosbags' in replay). A caller picks the path by
the bytes' encapsulation (:data:`~ccf_ros.messages.cdr.LITTLE_ENDIAN_CDR`) and then only calls the path's steps:
``read_imu`` -> the engine (``frame_id`` first while it wants the sensor frame) -> ``answer`` -> ``stamped`` /
``header``. Either way the values are exactly the engine's.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

from .cdr import (
    _F3,
    _F13,
    _HDR,
    ANGULAR_VELOCITY,
    LINEAR_ACCELERATION,
    frame_id,
    header,
    patch_imu_vectors,
    read_mag,
    reframe_imu,
    vector3_stamped,
)
from .convert import fill_imu, reframe_msg, stamp_s

if TYPE_CHECKING:
    from ..engine import Output

Vec3 = tuple[float, float, float]
#: What a path answers from: the input's bytes (fast path) or the deserialized message.
Src = TypeVar('Src')

__all__ = ['FastCdrPath', 'MessagePath', 'Path']


class Path(Protocol[Src]):
    """One way for an IMU or magnetometer message from its bytes to the engine and from the engine's output to the
    answer. A message that cannot be read raises (struct.error, ValueError, or the deserializer's error)."""

    #: whether answers are turned into the output frame (a new frame_id and/or rotated covariances)
    reframes: bool

    def read_imu(self, raw: bytes) -> tuple[float, Path[Src], Src, int, Vec3, Vec3]:
        """A serialized Imu as a caller holds it until answered: stamp (s), this path, the source to answer from,
        the offset of ``orientation`` in it (0 for a message), angular velocity (rad/s), linear acceleration (m/s²).
        (The path in the tuple saves the node building a second one per message.)"""
        ...

    def read_mag(self, raw: bytes) -> tuple[float, Vec3]:
        """Stamp (s) and magnetic field (T) of a serialized MagneticField."""
        ...

    def frame_id(self, src: Src) -> str:
        """The Imu's header.frame_id."""
        ...

    def answer(self, src: Src, off: int, out: Output) -> tuple[Any, Src, int]:
        """The Imu answering ``src`` with the engine's ``out`` (in the output frame) as the caller sends it, and the
        source and ``orientation`` offset that carry its header (a new frame_id moves the body)."""
        ...

    def stamped(self, src: Src, off: int, v: Vec3) -> Any:
        """A Vector3Stamped with ``src``'s header and vector ``v``."""
        ...

    def header(self, src: Src) -> tuple[int, int, str]:
        """``(sec, nanosec, frame_id)`` of ``src``'s header."""
        ...

    def set_output(self, frame: str, rot: Sequence[float] | None) -> None:
        """Answer in the output frame ``frame`` ('' keeps the input's frame_id), rotated by ``rot`` (row-major 3x3;
        None: not rotated)."""
        ...


class FastCdrPath:
    """Little-endian CDR: fields read from the bytes, the answer patched into a copy of them (:mod:`.cdr`).

    Args:
        frame, rot: see :meth:`set_output`.
        send: what the answered buffer becomes for the caller (``bytes`` for rclpy's publish, ``memoryview`` for a
            bag writer: no copy).
        tail: bytes an Imu must have after ``orientation`` (0: what :func:`~.cdr.read_imu` reads); shorter is a
            ValueError.
    """

    # As plain functions: a method wrapping them would cost a call per message.
    read_mag = staticmethod(read_mag)
    frame_id = staticmethod(frame_id)
    header = staticmethod(header)
    stamped = staticmethod(vector3_stamped)

    def __init__(self, frame: str = '', rot: Sequence[float] | None = None, *,
                 send: Callable[[bytearray], Any] = bytes, tail: int = 0) -> None:
        self._send = send
        self._tail = tail
        self.set_output(frame, rot)

    def set_output(self, frame: str, rot: Sequence[float] | None) -> None:
        self._frame = frame.encode() if frame else None
        self._rot = rot
        self.reframes = self._frame is not None or rot is not None

    def read_imu(self, raw: bytes) -> tuple[float, FastCdrPath, bytes, int, Vec3, Vec3]:
        # cdr.read_imu written out (the node calls this per message; a call costs as much as the reading): changes
        # together with it. A message too short for the fields raises struct.error, as there.
        sec, nsec, n = _HDR.unpack_from(raw, 4)
        off = ((n + 19) & ~7) + 4
        gyr: Vec3 = _F3.unpack_from(raw, off + ANGULAR_VELOCITY)
        acc: Vec3 = _F3.unpack_from(raw, off + LINEAR_ACCELERATION)
        if len(raw) < off + self._tail:
            raise ValueError('too short for an Imu')
        return sec + nsec * 1e-9, self, raw, off, gyr, acc

    def answer(self, src: bytes | bytearray, off: int, out: Output) -> tuple[Any, bytearray, int]:
        if self.reframes:
            # Output frame: a new frame_id moves the body; the input's rate and acceleration covariances turn.
            buf, off = reframe_imu(src, off, self._frame, self._rot)
        else:
            buf = bytearray(src)
        _F13.pack_into(buf, off, *out.orientation_xyzw, *out.covariance)  # cdr.patch_imu written out (one call less)
        if out.angular_velocity is not None or out.linear_acceleration is not None:
            patch_imu_vectors(buf, off, out.angular_velocity, out.linear_acceleration)
        return self._send(buf), buf, off


class MessagePath:
    """A deserialized message: the answer is filled into it (same header and fields).

    Args:
        deserialize_imu, deserialize_mag: serialized Imu / MagneticField -> message (rclpy's or rosbags' class).
        stamped: (header, v) -> a Vector3Stamped message with that header and vector.
        covariance: the 9 orientation covariance values -> the container the message class takes.
        frame, rot: see :meth:`set_output`.
    """

    def __init__(self, deserialize_imu: Callable[[bytes], Any], deserialize_mag: Callable[[bytes], Any],
                 stamped: Callable[[Any, Vec3], Any], covariance: Callable[[tuple[float, ...]], Any],
                 frame: str = '', rot: Sequence[float] | None = None) -> None:
        self._deserialize_imu = deserialize_imu
        self._deserialize_mag = deserialize_mag
        self._stamped = stamped
        self._covariance = covariance
        self.set_output(frame, rot)

    def set_output(self, frame: str, rot: Sequence[float] | None) -> None:
        self._frame = frame
        self._rot = rot
        self.reframes = bool(frame) or rot is not None

    def read_imu(self, raw: bytes) -> tuple[float, MessagePath, Any, int, Vec3, Vec3]:
        msg = self._deserialize_imu(raw)
        g, a = msg.angular_velocity, msg.linear_acceleration
        return stamp_s(msg.header), self, msg, 0, (g.x, g.y, g.z), (a.x, a.y, a.z)

    def read_mag(self, raw: bytes) -> tuple[float, Vec3]:
        msg = self._deserialize_mag(raw)
        f = msg.magnetic_field
        return stamp_s(msg.header), (f.x, f.y, f.z)

    @staticmethod
    def frame_id(src: Any) -> str:
        return str(src.header.frame_id)

    def answer(self, src: Any, off: int, out: Output) -> tuple[Any, Any, int]:
        fill_imu(src, out, self._covariance(out.covariance))
        if self.reframes:
            reframe_msg(src, self._frame, self._rot)
        return src, src, off

    def stamped(self, src: Any, off: int, v: Vec3) -> Any:
        return self._stamped(src.header, v)

    @staticmethod
    def header(src: Any) -> tuple[int, int, str]:
        h = src.header
        return h.stamp.sec, h.stamp.nanosec, h.frame_id
