"""Reading ROS bags (rosbag2 mcap/sqlite3 and ROS 1 .bag) through rosbags, with one error type for users."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core.pairing import MagPairer
from ..core.quaternion import from_xyzw
from ..errors import BagError

__all__ = ['BagError', 'ImuArrays', 'connections_for', 'open_bag', 'read_bools', 'read_imu_arrays', 'read_orientations',
           'stamp_s', 'typestore']


def typestore() -> Any:
    """The ROS 2 Jazzy type store used for every message we write."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


@contextmanager
def open_bag(path: str | Path) -> Iterator[Any]:
    """Open a rosbag2 directory (or its .mcap/.db3 file) or a ROS 1 ``.bag`` as a rosbags ``AnyReader``."""
    from rosbags.highlevel import AnyReader

    p = Path(path)
    if not p.exists():
        raise BagError(f'{p}: no such bag')
    if p.is_file() and p.suffix in ('.mcap', '.db3') and (p.parent / 'metadata.yaml').exists():
        p = p.parent
    try:
        reader = AnyReader([p], default_typestore=typestore())
        reader.open()
    except BagError:
        raise
    except Exception as err:  # rosbags raises several types; the user needs one line
        raise BagError(f'{p}: cannot open bag: {err}') from None
    try:
        yield reader
    finally:
        reader.close()


def stamp_s(header: Any) -> float:
    """Header stamp as float seconds."""
    return header.stamp.sec + header.stamp.nanosec * 1e-9


def connections_for(reader: Any, topic: str, required: bool = True) -> list[Any]:
    """Connections of ``topic``; raises :class:`BagError` listing the bag's topics if required and absent."""
    conns = [c for c in reader.connections if c.topic == topic]
    if required and not conns:
        have = ', '.join(sorted({c.topic for c in reader.connections})) or 'none'
        raise BagError(f'topic {topic} not in bag (topics: {have})')
    return conns


@dataclass
class ImuArrays:
    """IMU samples of a bag with the magnetometer paired as replay pairs it.

    Attributes: t_s (N,) header stamps; gyr (N,3) rad/s; acc (N,3) m/s²; mag (N,3) (NaN where none paired).
    """

    t_s: np.ndarray
    gyr: np.ndarray
    acc: np.ndarray
    mag: np.ndarray
    extra: dict[str, Any] = field(default_factory=dict)


def read_imu_arrays(
    path: str | Path,
    imu_topic: str = '/imu/data_raw',
    mag_topic: str | None = '/imu/mag',
    mag_timeout_s: float = 0.5,
) -> ImuArrays:
    """Read all IMU samples (and paired magnetometer samples) of a bag into arrays."""
    pairer = MagPairer(timeout_s=mag_timeout_s)
    t, g, a, m = [], [], [], []
    nan3 = (np.nan, np.nan, np.nan)
    with open_bag(path) as reader:
        conns = connections_for(reader, imu_topic)
        if mag_topic:
            conns += connections_for(reader, mag_topic, required=False)
        try:
            for conn, _, raw in reader.messages(connections=conns):
                msg = reader.deserialize(raw, conn.msgtype)
                if conn.topic == imu_topic:
                    ts = stamp_s(msg.header)
                    t.append(ts)
                    v = msg.angular_velocity
                    g.append((v.x, v.y, v.z))
                    v = msg.linear_acceleration
                    a.append((v.x, v.y, v.z))
                    mm = pairer.get(ts)
                    m.append(mm if mm is not None else nan3)
                else:
                    f = msg.magnetic_field
                    pairer.add(stamp_s(msg.header), (f.x, f.y, f.z))
        except BagError:
            raise
        except Exception as err:
            raise BagError(f'{path}: bag is unreadable or truncated: {err}') from None
    return ImuArrays(
        t_s=np.array(t, dtype=float),
        gyr=np.array(g, dtype=float).reshape(-1, 3),
        acc=np.array(a, dtype=float).reshape(-1, 3),
        mag=np.array(m, dtype=float).reshape(-1, 3),
    )


def orientation_of(msg: Any, msgtype: str) -> tuple[float, float, float, float]:
    """``[w, x, y, z]`` of an Imu, PoseStamped, QuaternionStamped or Odometry message (the one x,y,z,w flip)."""
    if msgtype.endswith('/Imu'):
        o = msg.orientation
    elif msgtype.endswith('/PoseStamped'):
        o = msg.pose.orientation
    elif msgtype.endswith('/QuaternionStamped'):
        o = msg.quaternion
    elif msgtype.endswith('/Odometry'):
        o = msg.pose.pose.orientation
    else:
        raise BagError(f'unsupported reference type {msgtype} (use Imu, PoseStamped, QuaternionStamped, Odometry)')
    return from_xyzw(o.x, o.y, o.z, o.w)


def read_orientations(path: str | Path, topic: str) -> tuple[np.ndarray, np.ndarray]:
    """Header stamps ``(N,)`` s and orientations ``(N, 4)`` ``[w, x, y, z]`` of a topic."""
    t, q = [], []
    with open_bag(path) as reader:
        conns = connections_for(reader, topic)
        try:
            for conn, _, raw in reader.messages(connections=conns):
                msg = reader.deserialize(raw, conn.msgtype)
                q.append(orientation_of(msg, conn.msgtype))
                t.append(stamp_s(msg.header))
        except BagError:
            raise
        except Exception as err:
            raise BagError(f'{path}: bag is unreadable or truncated: {err}') from None
    return np.array(t, dtype=float), np.array(q, dtype=float).reshape(-1, 4)


def read_bools(path: str | Path, topic: str) -> tuple[np.ndarray, np.ndarray]:
    """Receive times ``(N,)`` s (bag time, std_msgs has no header) and values ``(N,)`` of a Bool topic."""
    t, v = [], []
    with open_bag(path) as reader:
        conns = connections_for(reader, topic)
        for conn, ts, raw in reader.messages(connections=conns):
            t.append(ts * 1e-9)
            v.append(bool(reader.deserialize(raw, conn.msgtype).data))
    return np.array(t, dtype=float), np.array(v, dtype=bool)
