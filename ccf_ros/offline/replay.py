"""``ccf replay``: run the core over a recorded bag and write ``/imu/data`` and ``/imu/gyro_bias`` to a new bag.

``/imu/data`` is the input Imu with orientation and covariance filled in and, as the node publishes it, the
angular velocity and linear acceleration the engine gives (``bias_corrected_rate``, ``remove_gravity_vector``).
"""

from __future__ import annotations

import struct
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..engine import ImuEngine
from .bagio import (
    BagError,
    BagWriter,
    connections_for,
    deserialize,
    in_bag_order,
    open_bag,
    open_writer,
    read_messages,
    staged,
    typestore,
    unreadable,
)
from .fastcdr import LITTLE_ENDIAN_CDR, patch_imu, patch_imu_vectors, read_imu, read_mag, vector3_stamped


@dataclass
class ReplaySummary:
    """What a replay did: input samples, answered samples, skipped by reason, wall time (s)."""

    n_in: int = 0
    n_out: int = 0
    skipped: dict[str, int] = field(default_factory=dict)
    n_no_acc: int = 0
    n_no_mag: int = 0
    wall_s: float = 0.0

    def line(self) -> str:
        skipped = ', '.join(f'{k} {v}' for k, v in sorted(self.skipped.items())) or 'none'
        rate = self.n_in / self.wall_s if self.wall_s > 0 else float('nan')
        return (
            f'samples in {self.n_in}, out {self.n_out}, skipped: {skipped}; gyro-only (bad accelerometer) '
            f'{self.n_no_acc}, no heading (bad magnetometer) {self.n_no_mag}; {rate:,.0f} samples/s'
        )


def replay(
    bag_in: str | Path,
    bag_out: str | Path,
    engine: ImuEngine,
    *,
    imu_topic: str = '/imu/data_raw',
    mag_topic: str | None = '/imu/mag',
    out_imu_topic: str = '/imu/data',
    out_bias_topic: str = '/imu/gyro_bias',
    storage: str = 'mcap',
    copy_input: bool = False,
    overwrite: bool = False,
    progress: bool | None = None,
) -> ReplaySummary:
    """Replay ``bag_in`` through ``engine`` into a new rosbag2 ``bag_out``.

    Written to a temporary sibling and renamed at the end: an error or Ctrl-C leaves no half bag behind.

    Raises:
        BagError: unreadable input, missing IMU topic, output not writable, or ``bag_out`` exists without
            ``overwrite``. Anything the engine raises passes unchanged (it is a bug, not a bad bag).
    """
    bag_out = Path(bag_out)
    if bag_out.exists() and not overwrite:
        raise BagError(f'{bag_out} exists; pass --overwrite to replace it')
    if bag_out.resolve() == Path(bag_in).resolve():
        raise BagError('output bag must differ from the input bag')
    summary = ReplaySummary()
    t0 = time.perf_counter()
    with staged(bag_out) as tmp, open_bag(bag_in) as reader, open_writer(tmp, storage) as writer:
        summary.n_out = _replay(reader, writer, engine, bag_in, imu_topic, mag_topic, out_imu_topic, out_bias_topic,
                                copy_input, progress)
    summary.n_in = engine.n_in
    summary.skipped = engine.skipped_by_reason()
    summary.n_no_acc = engine.n_no_acc
    summary.n_no_mag = engine.n_no_mag
    summary.wall_s = time.perf_counter() - t0
    return summary


def _replay(
    reader: Any,
    writer: BagWriter,
    engine: ImuEngine,
    bag_in: str | Path,
    imu_topic: str,
    mag_topic: str | None,
    out_imu_topic: str,
    out_bias_topic: str,
    copy_input: bool,
    progress: bool | None,
) -> int:
    """The message loop of :func:`replay`; returns the number of IMU messages written.

    Only reading (rosbags, and the CDR bytes of the fast path) and writing are guarded: they raise
    :class:`BagError`. The engine runs unguarded.
    """
    ts = typestore()
    Imu = ts.types['sensor_msgs/msg/Imu']
    Vector3 = ts.types['geometry_msgs/msg/Vector3']
    Vector3Stamped = ts.types['geometry_msgs/msg/Vector3Stamped']
    serialize = ts.serialize_cdr
    imu_conns = connections_for(reader, imu_topic, msgtype='sensor_msgs/msg/Imu')
    mag_conns = (connections_for(reader, mag_topic, required=False, msgtype='sensor_msgs/msg/MagneticField')
                 if mag_topic else [])
    conns = list(reader.connections) if copy_input else in_bag_order(reader, imu_conns + mag_conns)
    n_total = sum(c.msgcount for c in imu_conns)
    is_ros1 = not reader.is2
    w_imu = writer.add_connection(out_imu_topic, Imu.__msgtype__, typestore=ts)
    w_bias = writer.add_connection(out_bias_topic, Vector3Stamped.__msgtype__, typestore=ts)
    w_copy: dict[int, Any] = {}
    if copy_input:
        for c in reader.connections:
            if c.topic in (out_imu_topic, out_bias_topic):
                continue
            w_copy[c.id] = writer.add_connection(c.topic, c.msgtype, typestore=ts)
    from tqdm import tqdm

    bar = tqdm(
        total=n_total,
        unit='msg',
        disable=(not sys.stderr.isatty()) if progress is None else not progress,
        desc='replay',
        mininterval=0.5,
    )
    imu_ids = {c.id for c in imu_conns}
    mag_ids = {c.id for c in mag_conns}
    on_imu = engine.on_imu
    # Serialized right away, so one buffer and one bias message serve every sample.
    cov_buf = np.zeros(9)
    bias_vec = Vector3(x=0.0, y=0.0, z=0.0)
    bias_msg = Vector3Stamped(header=None, vector=bias_vec)
    imu_type, bias_type = Imu.__msgtype__, Vector3Stamped.__msgtype__
    write = writer.write
    on_mag = engine.on_mag
    n_out = 0
    # Messages are handled in blocks: read a block, filter it, serialize and write it. The filter sees the same
    # calls in the same order as message by message, but runs in a tight loop.
    block: list[tuple[int, int, Any]] = []

    def flush() -> None:
        nonlocal n_out
        outs = []
        for kind, _, msg in block:
            if kind == 3:
                try:
                    t, off, g, a = read_imu(msg)
                except struct.error as err:  # CDR bytes shorter than an Imu
                    raise unreadable(bag_in, err) from err
                outs.append((on_imu(t, g, a), off))
            elif kind == 4:
                try:
                    t, f = read_mag(msg)
                except struct.error as err:
                    raise unreadable(bag_in, err) from err
                on_mag(t, f)
            elif kind == 0:
                h = msg.header
                g = msg.angular_velocity
                a = msg.linear_acceleration
                outs.append(on_imu(h.stamp.sec + h.stamp.nanosec * 1e-9, (g.x, g.y, g.z), (a.x, a.y, a.z)))  # type: ignore[arg-type]
            elif kind == 1:
                h = msg.header
                f = msg.magnetic_field
                on_mag(h.stamp.sec + h.stamp.nanosec * 1e-9, (f.x, f.y, f.z))
        n_imu = len(outs)
        it: Any = iter(outs)
        for kind, t_rec, msg in block:
            if kind == 3:
                out, off = next(it)
                if out is None:
                    continue
                buf = bytearray(msg)
                patch_imu(buf, off, out.orientation_xyzw, out.covariance)
                # bias_corrected_rate / remove_gravity_vector
                patch_imu_vectors(buf, off, out.angular_velocity, out.linear_acceleration)
                write(w_imu, t_rec, memoryview(buf))
                write(w_bias, t_rec, vector3_stamped(msg, off, out.bias))
                n_out += 1
            elif kind == 0:
                out = next(it)
                if out is None:
                    continue
                # Reuse the deserialized message: same header and fields, orientation filled in.
                o = msg.orientation
                o.x, o.y, o.z, o.w = out.orientation_xyzw
                cov_buf[:] = out.covariance
                msg.orientation_covariance = cov_buf
                if out.angular_velocity is not None:
                    v = msg.angular_velocity
                    v.x, v.y, v.z = out.angular_velocity
                if out.linear_acceleration is not None:
                    v = msg.linear_acceleration
                    v.x, v.y, v.z = out.linear_acceleration
                bias_vec.x, bias_vec.y, bias_vec.z = out.bias
                bias_msg.header = msg.header
                write(w_imu, t_rec, serialize(msg, imu_type))
                write(w_bias, t_rec, serialize(bias_msg, bias_type))
                n_out += 1
            elif kind == 2:
                write(msg[0], t_rec, msg[1])
        block.clear()
        bar.update(n_imu)

    try:
        for conn, t_rec, raw in read_messages(reader, bag_in, conns):
            cid = conn.id
            if cid in w_copy:
                if is_ros1:
                    try:
                        cdr = ts.ros1_to_cdr(raw, conn.msgtype)
                    except Exception as err:  # rosbags' conversion of a message that does not decode
                        raise unreadable(bag_in, err) from err
                else:
                    cdr = raw
                block.append((2, t_rec, (w_copy[cid], cdr)))
            # Little-endian CDR (rosbag2): read and patch the bytes; otherwise go through rosbags.
            fast = not is_ros1 and raw[:2] == LITTLE_ENDIAN_CDR
            if cid in imu_ids:
                block.append((3, t_rec, raw) if fast
                             else (0, t_rec, deserialize(reader, raw, conn.msgtype, bag_in)))
            elif cid in mag_ids:
                block.append((4, t_rec, raw) if fast
                             else (1, t_rec, deserialize(reader, raw, conn.msgtype, bag_in)))
            if len(block) >= 2048:
                flush()
        flush()
    finally:
        bar.close()
    return n_out
