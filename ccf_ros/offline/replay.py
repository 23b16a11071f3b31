"""``ccf replay``: run the core over a recorded bag and write ``/imu/data`` and ``/imu/gyro_bias`` to a new bag.

``/imu/data`` is the input Imu with orientation and covariance filled in and, as the node publishes it, the
angular velocity and linear acceleration the engine gives (``bias_corrected_rate``, ``remove_gravity_vector``).

How it runs: :func:`replay` opens the input bag and a staged output bag; :class:`_Replayer` reads the messages in
bag order and sends each IMU or magnetometer message down one of two paths with the same steps (:class:`_Path`, on
the paths the node takes too, :mod:`ccf_ros.messages.paths`): the fast path reads and patches little-endian CDR bytes
(rosbag2), the message path deserializes anything else (ROS 1, big-endian CDR) with rosbags. Messages are handled in blocks of :data:`BLOCK_SIZE`: the
filter runs over a block's samples in a tight loop, then the block's answers and copies are written, in order.
"""

from __future__ import annotations

import math
import struct
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple, Protocol

import numpy as np

from ..engine import ChunkAnswers, ImuEngine, Output, Vec3
from ..messages.cdr import ANGULAR_VELOCITY, LINEAR_ACCELERATION, LITTLE_ENDIAN_CDR, _gather, stamped_columns
from ..messages.convert import stamp_s
from ..messages.paths import FastCdrPath, MessagePath
from ..messages.paths import Path as MessageWay
from ..settings import MOTION_HINT_DEFAULT
from .bagio import (
    BagError,
    BagWriter,
    connections_for,
    deserialize,
    detect_topics,
    in_bag_order,
    open_bag,
    open_writer,
    read_messages,
    refuse_existing,
    ros1_to_cdr,
    staged,
    typestore,
    unreadable,
)

if TYPE_CHECKING:  # rosbags is imported when a bag is opened, not with this module
    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import Connection
    from rosbags.typesys.store import Typestore

IMU = 'sensor_msgs/msg/Imu'
MAGNETIC_FIELD = 'sensor_msgs/msg/MagneticField'
VECTOR3_STAMPED = 'geometry_msgs/msg/Vector3Stamped'

#: An MCAP message record's header: opcode 0x05, record length, channel id, sequence, log and publish time (ns).
_RECORD_HEAD = struct.Struct('<BQHIQQ')
_RECORD_DTYPE = np.dtype([('op', 'u1'), ('length', '<u8'), ('cid', '<u2'), ('seq', '<u4'), ('t', '<u8'),
                          ('t_pub', '<u8')])

#: Messages read before the filter runs over them and their answers are written. The filter sees the same calls in
#: the same order as message by message, but runs in a tight loop.
BLOCK_SIZE = 2048


@dataclass
class ReplaySummary:
    """What a replay did: input samples, answered samples, skipped by reason, wall time (s)."""

    n_in: int = 0
    n_out: int = 0
    skipped: dict[str, int] = field(default_factory=dict)
    n_no_acc: int = 0
    n_no_mag: int = 0
    wall_s: float = 0.0
    #: samples answered with the current orientation although they could not advance the filter
    n_answered_stale: int = 0
    n_resets_jump: int = 0
    n_nonfinite_resets: int = 0
    #: gyro samples at gyro_range_rad_s
    n_gyro_clipped: int = 0
    #: the filter's flags after the last sample (:class:`~ccf_ros.core.base.FilterFlags` as a dict)
    flags: dict[str, bool] = field(default_factory=dict)
    #: what the user should know about the run (e.g. no magnetometer topic in the bag), one sentence each
    warnings: list[str] = field(default_factory=list)

    def line(self) -> str:
        skipped = ', '.join(f'{k} {v}' for k, v in sorted(self.skipped.items())) or 'none'
        rate = self.n_in / self.wall_s if self.wall_s > 0 else float('nan')
        on = ', '.join(k for k, v in self.flags.items() if v) or 'none'
        return (
            f'samples in {self.n_in}, out {self.n_out}, skipped: {skipped} (these {self.n_answered_stale} answered with '
            f'the current orientation); gyro-only (bad accelerometer) {self.n_no_acc}, no heading (bad magnetometer) '
            f'{self.n_no_mag}; restarts after clock jumps {self.n_resets_jump}, non-finite state {self.n_nonfinite_resets}; '
            f'gyro clipped {self.n_gyro_clipped}; flags at the end: {on}; {rate:,.0f} samples/s'
        )


class HealthSink(Protocol):
    """What replay feeds IMU samples to besides the engine (``ccf fleet``'s health accumulator)."""

    def observe(self, engine: ImuEngine) -> None:
        """Take every sample ``engine.on_imu`` gets from now on (by wrapping it)."""
        ...

    def add_block(self, t: Any, gyr: Any, acc: Any, mag: Any, rejected: Any) -> None:
        """A chunk's IMU samples: stamps (N,) s, gyr and acc (N, 3), paired mag (N, 3) (NaN: none), gated (N,)."""
        ...


_NAN3 = (float('nan'),) * 3


class Topics(NamedTuple):
    """The topics replay reads (``mag`` None: none) and writes."""

    imu: str = '/imu/data_raw'
    mag: str | None = '/imu/mag'
    out_imu: str = '/imu/data'
    out_bias: str = '/imu/gyro_bias'
    #: a missing ``mag`` topic is an error (True: the user named it) or a 6-D run with a warning (False)
    mag_required: bool = False
    #: nav_msgs/Odometry or geometry_msgs/TwistStamped saying whether the robot moves (None: none)
    motion_hint: str | None = None


def replay(
    bag_in: str | Path,
    bag_out: str | Path,
    engine: ImuEngine,
    *,
    imu_topic: str | None = '/imu/data_raw',
    mag_topic: str | None = '/imu/mag',
    mag_required: bool = False,
    detect: bool = False,
    no_mag: bool = False,
    out_imu_topic: str = '/imu/data',
    out_bias_topic: str = '/imu/gyro_bias',
    storage: str = 'mcap',
    copy_input: bool = False,
    overwrite: bool = False,
    progress: bool | None = None,
    motion_hint_topic: str | None = None,
    motion_hint: tuple[float, float, float] = MOTION_HINT_DEFAULT,
    health: HealthSink | None = None,
) -> ReplaySummary:
    """Replay ``bag_in`` through ``engine`` into a new rosbag2 ``bag_out``.

    Written to a temporary sibling and renamed at the end: an error or Ctrl-C leaves no half bag behind.

    ``detect``: ``imu_topic`` None is the bag's one Imu topic, ``mag_topic`` None its one MagneticField topic
    (:func:`~ccf_ros.offline.bagio.detect_topics`; a named ``mag_topic`` is then required; ``no_mag``: none).
    A bag without ``mag_topic`` replays 6-D (heading relative to the start) with a warning in the summary, unless
    ``mag_required``, which makes it an error (the user named a topic, and a typo must not pass silently).

    ``motion_hint_topic`` (Odometry or TwistStamped) feeds :meth:`ImuEngine.on_motion_hint` in bag order, as the
    node does: still below ``motion_hint`` = (speed m/s, turn rate rad/s), counting for its timeout (s).

    ``health`` (``ccf fleet``'s :class:`~ccf_ros.fleet.health.HealthAccumulator`) gets every IMU sample the engine
    gets: a chunk's arrays at once on the bulk path, else sample by sample.

    Raises:
        BagError: unreadable input, missing or empty IMU topic, missing ``mag_topic`` with ``mag_required``, output
            not writable, or ``bag_out`` exists without ``overwrite`` (or is not a bag). Anything the engine raises
            passes unchanged (it is a bug, not a bad bag).
    """
    bag_out = Path(bag_out)
    if bag_out.resolve() == Path(bag_in).resolve() or bag_out.resolve() in Path(bag_in).resolve().parents:
        raise BagError(f'output {bag_out} must neither be the input bag nor a folder that holds it')
    refuse_existing(bag_out, overwrite)
    t0 = time.perf_counter()
    with open_bag(bag_in) as reader, staged(bag_out) as tmp, open_writer(tmp, storage) as writer:
        if detect:
            imu_topic, mag_topic, mag_required = detect_topics(reader, bag_in, imu_topic, mag_topic, no_mag)
        if imu_topic is None:
            raise BagError('replay: no IMU topic (pass imu_topic or detect=True)')
        topics = Topics(imu_topic, mag_topic, out_imu_topic, out_bias_topic, mag_required, motion_hint_topic)
        replayer = _Replayer(reader, writer, engine, bag_in, topics, copy_input, motion_hint, health)
        n_out = replayer.run(progress)
    warnings = engine.warnings + replayer.warnings
    if engine.settings.bias_file:
        try:
            engine.save_state(engine.settings.bias_file)
        except OSError as err:
            warnings.append(f'cannot write bias_file {engine.settings.bias_file}: {err}')
    return ReplaySummary(
        n_in=engine.n_in,
        n_out=n_out,
        skipped=engine.skipped_by_reason(),
        n_no_acc=engine.n_no_acc,
        n_no_mag=engine.n_no_mag,
        wall_s=time.perf_counter() - t0,
        n_answered_stale=engine.n_answered_stale,
        n_resets_jump=engine.n_resets_jump,
        n_nonfinite_resets=engine.n_nonfinite_resets,
        n_gyro_clipped=engine.n_gyro_clipped,
        flags=engine.filter.flags._asdict(),
        warnings=warnings,
    )


@dataclass(frozen=True)
class _Outputs:
    """The output bag's connections: the answers, and the input connections copied (by input connection id)."""

    writer: BagWriter
    imu: Connection
    bias: Connection
    copies: dict[int, Connection]

    @classmethod
    def add(cls, writer: BagWriter, reader: AnyReader, store: Typestore, topics: Topics, copy_input: bool) -> _Outputs:
        imu = writer.add_connection(topics.out_imu, IMU, typestore=store)
        bias = writer.add_connection(topics.out_bias, VECTOR3_STAMPED, typestore=store)
        copied = [c for c in reader.connections if c.topic not in (topics.out_imu, topics.out_bias)] if copy_input else []
        copies = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=store) for c in copied}
        return cls(writer, imu, bias, copies)


#: A serialized answer: the Imu and the Vector3Stamped of the gyro bias, CDR.
Serialized = tuple[bytes | memoryview, bytes | memoryview]


class _Path:
    """One way through replay for an IMU or magnetometer message, from its bytes as read from the bag to the bytes
    of the answer: one of the shared paths (:mod:`ccf_ros.messages.paths`: :class:`FastCdrPath` for little-endian
    CDR, :class:`MessagePath` for anything else, deserialized by rosbags), the engine, and the bag's rules (a message
    that cannot be read is a :class:`BagError`). Answers are (source, orientation offset, the engine's output).

    Args:
        serialize: (answer Imu, msgtype) -> CDR bytes (the message path's; the fast path's answers are bytes).
    """

    def __init__(self, way: MessageWay[Any], engine: ImuEngine, bag: str | Path,
                 serialize: Any = None) -> None:
        self.way = way
        self._engine = engine
        self._read_imu, self._read_mag = way.read_imu, way.read_mag
        self._answer, self._stamped = way.answer, way.stamped
        self._on_imu = engine.on_imu
        self._on_mag = engine.on_mag
        self._bag = bag
        self._serialize = serialize
        way.set_output(engine.settings.output_frame_id, engine.output_rotation)
        if engine.wants_sensor_frame:
            self.on_imu = self._first_imu  # type: ignore[method-assign]  # once: then the plain method

    def _first_imu(self, raw: bytes) -> tuple[Any, int, Output] | None:
        """The first IMU sample: tell the engine the sensor's frame_id (its bias_file applies from here)."""
        del self.on_imu
        if self._engine.wants_sensor_frame:
            try:
                self._engine.set_sensor_frame(self.way.frame_id(self._read_imu(raw)[2]))
            except (struct.error, IndexError) as err:
                raise unreadable(self._bag, err) from err
        return self.on_imu(raw)

    def on_imu(self, raw: bytes) -> tuple[Any, int, Output] | None:
        """Feed an IMU sample to the engine; None: the engine gives no answer (nothing is written)."""
        try:
            t, _, src, off, gyr, acc = self._read_imu(raw)
        except struct.error as err:  # CDR bytes shorter than an Imu
            raise unreadable(self._bag, err) from err
        out = self._on_imu(t, gyr, acc)
        return None if out is None else (src, off, out)

    def on_mag(self, raw: bytes) -> None:
        """Feed a magnetometer sample to the engine."""
        try:
            t, f = self._read_mag(raw)
        except struct.error as err:
            raise unreadable(self._bag, err) from err
        self._on_mag(t, f)

    def serialize(self, answer: tuple[Any, int, Output]) -> Serialized:
        """The messages that answer an IMU sample."""
        src, off, out = answer
        imu, src, off = self._answer(src, off, out)
        bias = self._stamped(src, off, out.bias)
        serialize = self._serialize
        if serialize is None:
            return imu, bias
        return serialize(imu, IMU), serialize(bias, VECTOR3_STAMPED)


def _fast_path(engine: ImuEngine, bag: str | Path) -> _Path:
    """Little-endian CDR (rosbag2): no deserialisation; answers are views of the patched copies."""
    return _Path(FastCdrPath(send=memoryview), engine, bag)


def _message_path(engine: ImuEngine, reader: AnyReader, store: Typestore, bag: str | Path) -> _Path:
    """Anything else (ROS 1, big-endian CDR): rosbags deserializes the message; the answer is filled into it and it
    is serialized again (same header and fields)."""
    # rosbags' message classes are generated: their fields are not known statically.
    types: dict[str, Any] = store.types
    # Serialized right away, so one covariance buffer and one bias message serve every sample.
    covariance = np.zeros(9)
    vector = types['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=0.0)
    bias = types[VECTOR3_STAMPED](header=None, vector=vector)

    def fill_covariance(values: tuple[float, ...]) -> Any:
        covariance[:] = values
        return covariance

    def stamped(header: Any, v: Vec3) -> Any:
        vector.x, vector.y, vector.z = v
        bias.header = header
        return bias

    way = MessagePath(lambda raw: deserialize(reader, raw, IMU, bag),
                      lambda raw: deserialize(reader, raw, MAGNETIC_FIELD, bag), stamped, fill_covariance)
    return _Path(way, engine, bag, store.serialize_cdr)


class _HintPath:
    """Motion-hint messages (nav_msgs/Odometry or geometry_msgs/TwistStamped, deserialized: tens of Hz) to
    :meth:`ImuEngine.on_motion_hint`, with the node's rule: still below both thresholds."""

    def __init__(self, engine: ImuEngine, reader: AnyReader, bag: str | Path, hint: tuple[float, float, float]) -> None:
        self._engine = engine
        self._reader = reader
        self._bag = bag
        lin, ang, self._timeout = hint
        self._lin2, self._ang2 = lin * lin, ang * ang
        self.msgtype = ''

    def on_hint(self, raw: bytes) -> None:
        msg = deserialize(self._reader, raw, self.msgtype, self._bag)
        tw = msg.twist.twist if self.msgtype == ODOMETRY else msg.twist
        v, w = tw.linear, tw.angular
        v2 = v.x * v.x + v.y * v.y + v.z * v.z
        w2 = w.x * w.x + w.y * w.y + w.z * w.z
        if math.isfinite(v2) and math.isfinite(w2):  # (a non-finite twist says nothing: skipped, as the node does)
            self._engine.on_motion_hint(stamp_s(msg.header), v2 < self._lin2 and w2 < self._ang2, self._timeout)


class Kind(Enum):
    """What a message of a block is for."""

    IMU = 'imu'  # fed to the engine, answered on the output topics
    MAG = 'mag'  # fed to the engine
    HINT = 'hint'  # fed to the engine (motion hint)
    COPY = 'copy'  # written to the output as it is (``copy_input``)


# As plain module globals for the message loops: each Kind.IMU there would cost an enum attribute lookup.
_IMU, _MAG, _HINT, _COPY = Kind.IMU, Kind.MAG, Kind.HINT, Kind.COPY
ODOMETRY, TWIST_STAMPED = 'nav_msgs/msg/Odometry', 'geometry_msgs/msg/TwistStamped'

#: One message of a block: its kind; its :class:`_Path` (None for a copy); its receive time, ns; its bytes as read
#: (for a copy: the output connection and the CDR bytes).
_Entry = tuple[Kind, Any, int, Any]


def decode_chunk(cols: Any, imu: Any) -> tuple[Any, Any, Any, Any, Any, Any] | None:
    """A chunk's IMU and magnetometer messages (``imu`` (N,) bool: which are IMU; :class:`~ccf_ros.offline.mcap._Columns`)
    decoded with numpy as :func:`read_imu` and :func:`read_mag` decode one: the bytes ``u8``, the IMU messages'
    indices (M,) and body offsets (M,), stamps ``t`` (N,) s, and (N, 3) ``v1`` (rate, or field) and ``v2``
    (acceleration; 0 for a magnetometer). None if a message is not little-endian CDR or too short."""
    u8 = np.frombuffer(cols.buf, dtype=np.uint8)
    ii, mi = np.flatnonzero(imu), np.flatnonzero(~imu)
    imu_cols = stamped_columns(u8, cols.start[ii], cols.end[ii], LINEAR_ACCELERATION + 24)
    mag_cols = stamped_columns(u8, cols.start[mi], cols.end[mi], 24)
    if imu_cols is None or mag_cols is None:
        return None
    (t_imu, body), (t_mag, mag_body) = imu_cols, mag_cols
    n = len(imu)
    t_all = np.empty(n)
    v1, v2 = np.zeros((n, 3)), np.zeros((n, 3))
    t_all[ii], t_all[mi] = t_imu, t_mag
    at = cols.start[ii] + body
    v1[ii] = _gather(u8, at + ANGULAR_VELOCITY, 24, '<f8')
    v2[ii] = _gather(u8, at + LINEAR_ACCELERATION, 24, '<f8')
    v1[mi] = _gather(u8, cols.start[mi] + mag_body, 24, '<f8')
    return u8, ii, body, t_all, v1, v2


def feed_chunk(engine: ImuEngine, imu: Any, ii: Any, t_all: Any, v1: Any, v2: Any, health: HealthSink | None = None,
               answers: bool = True) -> ChunkAnswers:
    """A decoded chunk (:func:`decode_chunk`'s ``ii``, ``t_all``, ``v1``, ``v2``; ``imu`` (N,) bool) through the
    engine in order (:meth:`ImuEngine.on_chunk`: the same calls with the same floats as message by message).
    Returns the answers as columns; ``health``, if given, gets the chunk's arrays with the paired magnetometer
    samples and the gate's verdicts. One call per chunk: the per-sample loop stays inside. ``answers`` False: no
    answers are collected (the health-only task)."""
    # Columns of floats, not a list per row: nothing for the garbage collector to track.
    ans = engine.on_chunk(imu.tolist(), t_all.tolist(), tuple(v1.T.tolist()), tuple(v2.T.tolist()),
                          observe=health is not None, answers=answers)
    if health is not None:
        assert ans.paired_mag is not None and ans.mag_rejected is not None
        mag = np.array(ans.paired_mag, dtype=float).reshape(-1, 3)
        health.add_block(t_all[ii], v1[ii], v2[ii], mag, np.array(ans.mag_rejected, dtype=bool))
    return ans


class _Replayer:
    """The message loop of :func:`replay`: reads the input in blocks, feeds the engine, writes the output.

    Only reading (rosbags, and the CDR bytes of the fast path) and writing are guarded: they raise
    :class:`BagError`. The engine runs unguarded.
    """

    def __init__(
        self, reader: AnyReader, writer: BagWriter, engine: ImuEngine, bag: str | Path, topics: Topics,
        copy_input: bool, motion_hint: tuple[float, float, float] = MOTION_HINT_DEFAULT,
        health: HealthSink | None = None,
    ) -> None:
        imu_conns = connections_for(reader, topics.imu, msgtype=IMU)
        mag_conns = (
            connections_for(reader, topics.mag, required=topics.mag_required, msgtype=MAGNETIC_FIELD)
            if topics.mag else []
        )
        self.warnings: list[str] = []
        n_mag = sum(c.msgcount for c in mag_conns)
        if topics.mag and topics.mag_required and mag_conns and not n_mag:
            raise BagError(f'{bag}: no messages on {topics.mag}')
        if topics.mag and not n_mag and getattr(engine.filter.params, 'use_mag', True):
            self.warnings.append(f'no {topics.mag} in the bag: 6-D, heading relative to the start (--mag-topic names '
                                 'another topic, --no-mag silences this)')
        self._reader = reader
        self._engine = engine
        self._health = health
        self._bag = bag
        self._hint = _HintPath(engine, reader, bag, motion_hint)
        hint_conns = connections_for(reader, topics.motion_hint) if topics.motion_hint else []
        for c in hint_conns:
            if c.msgtype not in (ODOMETRY, TWIST_STAMPED):
                raise BagError(f'topic {c.topic} is {c.msgtype}, expected {ODOMETRY} or {TWIST_STAMPED}')
            self._hint.msgtype = c.msgtype
        self._inputs = (list(reader.connections) if copy_input
                        else in_bag_order(reader, imu_conns + mag_conns + hint_conns))
        #: Input connection id -> what its messages are for (copies aside).
        self._kinds = ({c.id: _MAG for c in mag_conns} | {c.id: _IMU for c in imu_conns}
                       | {c.id: _HINT for c in hint_conns})
        self._n_imu = sum(c.msgcount for c in imu_conns)
        if not self._n_imu:
            raise BagError(f'{bag}: no messages on {topics.imu}')
        self._store = typestore()
        self._outputs = _Outputs.add(writer, reader, self._store, topics, copy_input)
        if copy_input and (own := sorted({c.topic for c in reader.connections} & {topics.out_imu, topics.out_bias})):
            # One topic cannot hold both the input's messages and the replay's answers.
            self.warnings.append(f'{", ".join(own)} of the input not copied: the output\'s are the replay\'s')
        self._fast = _fast_path(engine, bag)
        self._message = _message_path(engine, reader, self._store, bag)

    def run(self, progress: bool | None) -> int:
        """Replay every message; returns the number of IMU messages written. ``progress`` None: a bar on a tty."""
        from tqdm import tqdm

        bar = tqdm(
            total=self._n_imu,
            unit='msg',
            disable=(not sys.stderr.isatty()) if progress is None else not progress,
            desc='replay',
            mininterval=0.5,
        )
        n_out = 0
        try:
            bulk = self._bulk()
            if bulk is None and self._health is not None:
                self._health.observe(self._engine)  # (before the paths take the engine's on_imu)
                self._fast = _fast_path(self._engine, self._bag)
                self._message = _message_path(self._engine, self._reader, self._store, self._bag)
            if bulk is not None:
                for n_o, n_imu in bulk:
                    n_out += n_o
                    bar.update(n_imu)
                return n_out
            for block in self._blocks():
                answers, n_imu = self._filter(block)
                n_out += self._write(block, answers)
                bar.update(n_imu)
        finally:
            bar.close()
        return n_out

    def _bulk(self) -> Iterator[tuple[int, int]] | None:
        """The bulk path, where it applies: a single-file MCAP input read a chunk at a time (:func:`fast_batches`),
        the output's records framed with numpy from the input's bytes (:func:`record_writer`); nothing to copy, no
        motion hint, no output frame, no state file waiting for the sensor's frame_id. Yields (answers, IMU samples)
        per chunk; None where it does not apply."""
        if (self._outputs.copies or not self._reader.is2 or self._fast.way.reframes or self._hint.msgtype
                or self._engine.wants_sensor_frame):
            return None
        from .mcap import McapError, fast_batches, record_writer

        write_records = record_writer(self._outputs.writer.writer)
        if write_records is None:
            return None
        try:
            batches = fast_batches(self._reader, self._inputs)
        except (McapError, OSError) as err:
            raise unreadable(self._bag, err) from err
        if batches is None:
            return None
        return self._bulk_run(batches, write_records)

    def _bulk_run(self, batches: Iterator[Any], write_records: Any) -> Iterator[tuple[int, int]]:
        is_imu = np.array([self._kinds[c.id] is _IMU for c in self._inputs])
        while True:
            try:
                cols = next(batches)
            except StopIteration:
                return
            except Exception as err:  # a malformed chunk (McapError, zstd/lz4 errors, a short file)
                raise unreadable(self._bag, err) from err
            done = self._bulk_chunk(cols, is_imu[cols.owner], write_records)
            if done is None:  # not all little-endian CDR, or a short message: message by message
                block = self._entries(cols)
                answers, n_imu = self._filter_observed(block) if self._health is not None else self._filter(block)
                done = self._write(block, answers), n_imu
            yield done

    def _filter_observed(self, block: list[_Entry]) -> tuple[list[Any], int]:
        """:meth:`_filter`, the IMU samples also given to the health sink, as arrays (as the bulk path does)."""
        assert self._health is not None
        engine, rows = self._engine, []
        filt = engine.filter
        gated = hasattr(filt, 'mag_disturbed')
        on_imu = engine.on_imu

        def observed(t_s: float, gyr: Vec3, acc: Vec3) -> Output | None:
            out = on_imu(t_s, gyr, acc)
            rows.append((t_s, gyr, acc, engine.paired_mag or _NAN3, gated and filt.mag_disturbed))
            return out

        paths = (self._fast, self._message)
        for p in paths:
            p._on_imu = observed
        try:
            found = self._filter(block)
        finally:
            for p in paths:
                p._on_imu = on_imu
        if rows:
            t, g, a, m, r = zip(*rows, strict=True)
            self._health.add_block(np.array(t, dtype=float), np.array(g, dtype=float), np.array(a, dtype=float),
                                   np.array(m, dtype=float), np.array(r, dtype=bool))
        return found

    def _entries(self, cols: Any) -> list[_Entry]:
        """A chunk's messages as :meth:`_blocks` gives them."""
        fast_path, message_path, kinds = self._fast, self._message, self._kinds
        buf = cols.buf
        out: list[_Entry] = []
        for k, t, a, b in zip(cols.owner.tolist(), cols.t_ns.tolist(), cols.start.tolist(), cols.end.tolist(),
                              strict=True):
            raw = buf[a:b]
            out.append((kinds[self._inputs[k].id], fast_path if raw[:2] == LITTLE_ENDIAN_CDR else message_path, t, raw))
        return out

    def _bulk_chunk(self, cols: Any, imu: Any, write_records: Any) -> tuple[int, int] | None:
        """One chunk's messages through the engine, in order, and its answers written; (answers, IMU samples), or
        None if the chunk needs the message path (nothing done then)."""
        dec = decode_chunk(cols, imu)
        if dec is None:
            return None
        u8, ii, body, t_all, v1, v2 = dec
        ans = feed_chunk(self._engine, imu, ii, t_all, v1, v2, self._health)
        if ans.answered:
            sel = np.array(ans.answered)
            with self._outputs.writer.guarded():  # (its file-system errors are BagError)
                write_records(*self._records(u8, cols.start[ii[sel]], cols.end[ii[sel]], body[sel],
                                             cols.t_ns[ii[sel]], ans))
        return len(ans.answered), len(ii)

    def _records(self, u8: Any, start: Any, end: Any, body: Any, t_ns: Any, ans: ChunkAnswers) -> tuple[Any, ...]:
        """The framed MCAP records of the answers (Imu, bias, Imu, bias, ...): the input Imu's bytes patched with
        numpy where every message has the same length and header (the usual case), else one by one."""
        imu_id, bias_id = self._outputs.imu.id, self._outputs.bias.id
        m = len(ans.answered)
        times = np.repeat(t_ns, 2)
        cids = np.tile(np.array([imu_id, bias_id], dtype=np.int64), m)
        lengths = end - start
        # The orientation (message order x, y, z, w) and the covariance: 13 doubles from the orientation's offset.
        q = np.array(ans.quaternion, dtype=float).reshape(m, 4)
        patch = np.zeros((m, 13))
        patch[:, 0:3], patch[:, 3] = q[:, 1:], q[:, 0]
        patch[:, 4::4] = np.array(ans.variance, dtype=float).reshape(m, 3)
        bias = np.array(ans.bias, dtype='<f8').reshape(m, 3)
        if not ((lengths == lengths[0]).all() and (body == body[0]).all()):
            parts: list[Any] = []
            sizes: list[int] = []
            for k, (s, e, off, t) in enumerate(zip(start.tolist(), end.tolist(), body.tolist(), t_ns.tolist(),
                                                   strict=True)):
                p = patch[k].tolist()
                out = Output((p[0], p[1], p[2], p[3]), tuple(p[4:]), tuple(bias[k].tolist()), 0,
                             None if ans.rate is None else ans.rate[k],
                             None if ans.linear_acceleration is None else ans.linear_acceleration[k])
                imu, b = self._fast.serialize((u8[s:e].tobytes(), off, out))
                for cid, data in ((imu_id, imu), (bias_id, b)):
                    parts += (_RECORD_HEAD.pack(0x05, 22 + len(data), cid, 0, t, t), data)
                    sizes.append(31 + len(data))
            return b''.join(parts), cids, times, sizes
        size, off = int(lengths[0]), int(body[0])
        rows = u8[start[:, None] + np.arange(size)]
        rows[:, off:off + 104] = patch.astype('<f8').view(np.uint8)
        if ans.rate is not None:
            rows[:, off + ANGULAR_VELOCITY:off + ANGULAR_VELOCITY + 24] = np.array(
                ans.rate, dtype='<f8').view(np.uint8)
        if ans.linear_acceleration is not None:
            rows[:, off + LINEAR_ACCELERATION:off + LINEAR_ACCELERATION + 24] = np.array(
                ans.linear_acceleration, dtype='<f8').view(np.uint8)
        r_imu, r_bias = 31 + size, 31 + off + 24
        rec = np.empty((m, r_imu + r_bias), dtype=np.uint8)
        head = np.zeros(m, dtype=_RECORD_DTYPE)
        head['op'], head['t'], head['t_pub'] = 0x05, t_ns, t_ns
        head['length'], head['cid'] = 22 + size, imu_id
        rec[:, :31] = head.view(np.uint8).reshape(m, 31)
        rec[:, 31:r_imu] = rows
        head['length'], head['cid'] = 22 + off + 24, bias_id
        rec[:, r_imu:r_imu + 31] = head.view(np.uint8).reshape(m, 31)
        rec[:, r_imu + 31:r_imu + 31 + off] = rows[:, :off]
        rec[:, r_imu + 31 + off:] = bias.view(np.uint8)
        return rec.reshape(-1), cids, times, np.tile(np.array([r_imu, r_bias], dtype=np.int64), m)

    def _blocks(self) -> Iterator[list[_Entry]]:
        """The input's messages in bag order, in blocks of about :data:`BLOCK_SIZE` entries: a message to copy, a
        sample for the filter on the path its bytes call for, or both (a copied IMU or magnetometer message)."""
        kinds, copies, fast_path, message_path = self._kinds, self._outputs.copies, self._fast, self._message
        ros1 = not self._reader.is2
        block: list[_Entry] = []
        add = block.append
        for conn, t_rec, raw in read_messages(self._reader, self._bag, self._inputs, fast=True):
            cid = conn.id
            if cid in copies:
                cdr = ros1_to_cdr(self._store, raw, conn.msgtype, self._bag) if ros1 else raw
                add((_COPY, None, t_rec, (copies[cid], cdr)))
            if cid in kinds:
                kind = kinds[cid]
                fast = not ros1 and raw[:2] == LITTLE_ENDIAN_CDR
                add((kind, self._hint if kind is _HINT else fast_path if fast else message_path, t_rec, raw))
            if len(block) >= BLOCK_SIZE:
                yield block
                block = []
                add = block.append
        yield block

    @staticmethod
    def _filter(block: list[_Entry]) -> tuple[list[Any], int]:
        """The engine over a block's samples, in order: per entry the answer of its path (None: none), and the
        number of IMU samples."""
        answers: list[Any] = []
        add = answers.append
        n_imu = 0
        for kind, path, _, raw in block:
            if kind is _IMU:
                add(path.on_imu(raw))
                n_imu += 1
            else:
                if kind is _MAG:
                    path.on_mag(raw)
                elif kind is _HINT:
                    path.on_hint(raw)
                add(None)
        return answers, n_imu

    def _write(self, block: list[_Entry], answers: list[Any]) -> int:
        """Write a block's answers and copies, in order; returns the number of answers.

        One write guard for the block (:meth:`BagWriter.guarded`): serializing an answer inside it does no I/O."""
        out_imu, out_bias = self._outputs.imu, self._outputs.bias
        n_out = 0
        with self._outputs.writer.guarded() as write:
            for (kind, path, t_rec, raw), answer in zip(block, answers, strict=True):
                if kind is _COPY:
                    conn_out, cdr = raw
                    write(conn_out, t_rec, cdr)
                elif answer is not None:
                    imu, bias = path.serialize(answer)
                    write(out_imu, t_rec, imu)
                    write(out_bias, t_rec, bias)
                    n_out += 1
        return n_out
