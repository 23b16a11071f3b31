"""Direct access to the few fields the node and replay need in little-endian CDR messages (rosbag2, rclpy's raw
messages), skipping full deserialisation: an Imu is read and its orientation and covariance are patched in place; a
Vector3Stamped is built.

Layouts (offsets after the 4-byte encapsulation header, 8-byte fields aligned to 8 from there):
``Header = int32 sec, uint32 nanosec, string frame_id (uint32 length incl. NUL, bytes)``, then the message's
float64 fields. Anything else (ROS 1, big-endian) goes through rosbags.
"""

from __future__ import annotations

import functools
import struct
from collections.abc import Sequence
from typing import Any

from ..frames import rotate_covariance

Vec3 = tuple[float, float, float]

LITTLE_ENDIAN_CDR = b'\x00\x01'
_HDR = struct.Struct('<iiI')  # sec, nanosec (as int; < 1e9 fits), frame_id length
_HEADER = struct.Struct('<iII')  # sec, nanosec as the message has it (uint32), frame_id length (with its NUL)
_F3 = struct.Struct('<3d')
_F13 = struct.Struct('<13d')  # orientation (4) and orientation_covariance (9), adjacent


# The offset of the first float64 field after the header, with the header at 4 (after the encapsulation) and a
# frame_id of n bytes with its NUL: ((n + 19) & ~7) + 4 (4 + 8 + 4 + n bytes, aligned to 8 from the data start).
# Written out in read_imu, read_mag and FastCdrPath.read_imu (per message: a call would cost as much as the reading)
# and vectorized in stamped_columns; the copies change together (tested for every n mod 8).


def read_imu(raw: bytes | bytearray | memoryview) -> tuple[float, int, Vec3, Vec3]:
    """Stamp (s), offset of ``orientation``, angular velocity (rad/s), linear acceleration (m/s²) of an Imu."""
    sec, nsec, n = _HDR.unpack_from(raw, 4)
    off = ((n + 19) & ~7) + 4  # the body offset's rule (see above)
    # Annotated, not cast(): typing.cast is a function call per message.
    gyr: Vec3 = _F3.unpack_from(raw, off + ANGULAR_VELOCITY)
    acc: Vec3 = _F3.unpack_from(raw, off + LINEAR_ACCELERATION)
    return sec + nsec * 1e-9, off, gyr, acc  # convert.seconds' rule, written out (changes together with it)


def patch_imu(buf: bytearray, off: int, xyzw: tuple[float, float, float, float], cov: tuple[float, ...]) -> None:
    """Write orientation (x, y, z, w) and orientation_covariance (9) into a serialized Imu at ``off``. (Written out
    in ``FastCdrPath.answer``: changes together with it.)"""
    _F13.pack_into(buf, off, *xyzw, *cov)


#: Offsets of angular_velocity and linear_acceleration from ``orientation`` (the offset :func:`read_imu` returns):
#: after 4 + 9 and 4 + 9 + 3 + 9 float64.
ANGULAR_VELOCITY = 104
LINEAR_ACCELERATION = 200


def patch_imu_vectors(buf: bytearray, off: int, gyr: Vec3 | None, acc: Vec3 | None) -> None:
    """Overwrite angular_velocity and/or linear_acceleration (None: keep) in a serialized Imu at ``off``."""
    if gyr is not None:
        _F3.pack_into(buf, off + ANGULAR_VELOCITY, *gyr)
    if acc is not None:
        _F3.pack_into(buf, off + LINEAR_ACCELERATION, *acc)


def read_mag(raw: bytes | bytearray | memoryview) -> tuple[float, Vec3]:
    """Stamp (s) and magnetic field of a serialized MagneticField."""
    sec, nsec, n = _HDR.unpack_from(raw, 4)
    field: Vec3 = _F3.unpack_from(raw, ((n + 19) & ~7) + 4)  # the body offset's rule (see above)
    return sec + nsec * 1e-9, field  # convert.seconds' rule, written out (changes together with it)


def vector3_stamped(imu_raw: bytes | bytearray | memoryview, imu_off: int, v: Vec3) -> bytes:
    """A serialized Vector3Stamped with the Imu's header (bytes up to ``imu_off``) and vector ``v``."""
    return bytes(imu_raw[:imu_off]) + _F3.pack(*v)


#: Offsets of angular_velocity_covariance and linear_acceleration_covariance from ``orientation``.
ANGULAR_VELOCITY_COVARIANCE = 128
LINEAR_ACCELERATION_COVARIANCE = 224
_F9 = struct.Struct('<9d')


def frame_id(raw: bytes | bytearray | memoryview) -> str:
    """The header's frame_id of a little-endian CDR message that starts with a std_msgs/Header."""
    return header(raw)[2]


def header(raw: bytes | bytearray | memoryview) -> tuple[int, int, str]:
    """``(sec, nanosec, frame_id)`` of a little-endian CDR message that starts with a std_msgs/Header."""
    sec, nanosec, n = _HEADER.unpack_from(raw, 4)
    return sec, nanosec, bytes(raw[16:16 + max(n - 1, 0)]).decode('utf-8', 'replace')


def reframe_imu(
    raw: bytes | bytearray | memoryview, off: int, new_frame_id: bytes | None, rot: Sequence[float] | None,
) -> tuple[bytearray, int]:
    """A copy of a serialized Imu with header.frame_id ``new_frame_id`` (UTF-8, None: kept) and its
    angular_velocity_covariance and linear_acceleration_covariance turned by ``rot`` (row-major 3x3, None: kept);
    returns it and the new offset of ``orientation`` (the body moves with the frame_id's length)."""
    if new_frame_id is None:
        buf = bytearray(raw)
    else:
        mid, new_off = _frame_field(new_frame_id)
        buf = bytearray(memoryview(raw)[:12])
        buf += mid
        buf += memoryview(raw)[off:]
        off = new_off
    if rot is not None:
        for at in (ANGULAR_VELOCITY_COVARIANCE, LINEAR_ACCELERATION_COVARIANCE):
            cov = _F9.unpack_from(buf, off + at)
            turned = rotate_covariance(rot, cov)
            if turned is not cov:
                _F9.pack_into(buf, off + at, *turned)
    return buf, off


@functools.lru_cache(maxsize=8)
def _frame_field(frame_id: bytes) -> tuple[bytes, int]:
    """The serialized frame_id string (length, bytes, NUL) with the padding up to the body, and the body's offset."""
    n = len(frame_id) + 1
    end = 16 + n  # after the string's NUL, in the buffer (data start at 4)
    new_off = ((end - 4 + 7) & ~7) + 4
    return struct.pack('<I', n) + frame_id + b'\x00' * (1 + new_off - end), new_off


# --- many messages at once (numpy): the fields of :func:`read_imu` and :func:`read_mag` for a chunk's messages ---

def _gather(u8: Any, at: Any, size: int, dtype: str) -> Any:
    """``size`` bytes at each offset ``at`` (N,) of ``u8``, as (N, size / itemsize) of ``dtype``."""
    import numpy as np

    return u8[at[:, None] + np.arange(size)].view(dtype)


def stamped_columns(u8: Any, start: Any, end: Any, fields_end: int) -> tuple[Any, Any] | None:
    """Stamps (s, by :func:`~ccf_ros.messages.convert.seconds`' rule) and body offsets (from each message's start)
    of little-endian CDR messages starting with a Header, at ``start`` (N,) in ``u8``; None if one is not
    little-endian or is shorter than ``fields_end`` bytes after its body offset (the message path says what)."""
    import numpy as np

    if not len(start):
        z = np.zeros(0)
        return z, z.astype(np.int64)
    if (u8[start] != 0).any() or (u8[start + 1] != 1).any() or (end - start < 16).any():
        return None
    head = _gather(u8, start + 4, 12, '<u4')
    sec, nsec, n = head[:, 0].view('<i4').astype(np.float64), head[:, 1].astype(np.float64), head[:, 2]
    body = ((12 + n.astype(np.int64) + 7) & ~7) + 4
    if (start + body + fields_end > end).any():
        return None
    return sec + nsec * 1e-9, body
