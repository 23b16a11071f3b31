"""Reading and writing ROS bags (rosbag2 mcap/sqlite3 and ROS 1 .bag) through rosbags, with one error type for users.

The ``try`` blocks here hold the rosbags calls only: what rosbags raises on a missing, unreadable or truncated bag
becomes a :class:`BagError` (chained ``from`` the original); an exception raised by the caller's code between
messages passes unchanged (a bug shows its traceback).
"""

from __future__ import annotations

import math
import shutil
import sqlite3
import sys
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.pairing import MagPairer
from ..core.quaternion import from_xyzw
from ..errors import BagError
from ..messages.convert import stamp_s

if TYPE_CHECKING:  # rosbags is imported when a bag is opened, not with this module
    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import Connection
    from rosbags.rosbag2 import Writer
    from rosbags.typesys.store import Typestore

__all__ = [
    'BagError', 'BagWriter', 'ImuArrays', 'connections_for', 'deserialize', 'detect_topics', 'in_bag_order', 'open_bag', 'open_writer',
    'read_bools', 'read_imu_arrays', 'read_messages', 'read_orientations', 'read_topic', 'refuse_existing', 'ros1_to_cdr',
    'staged', 'stamp_s', 'typestore', 'unreadable',
]

#: Storage plugins by the names ``--storage`` takes.
STORAGES = ('mcap', 'sqlite3')


def typestore() -> Typestore:
    """The ROS 2 Jazzy type store used for every message we write."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def unreadable(path: str | Path, err: BaseException) -> BagError:
    """The one error for a bag whose messages cannot be read (raise it ``from err``)."""
    return BagError(f'{path}: bag is unreadable or truncated: {type(err).__name__}: {err}')


@contextmanager
def open_bag(path: str | Path) -> Iterator[AnyReader]:
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
    except Exception as err:  # rosbags raises several types; the user needs one line
        raise BagError(f'{p}: cannot open bag: {type(err).__name__}: {err}') from err
    try:
        yield reader
    finally:
        reader.close()


def read_messages(
    reader: AnyReader, path: str | Path, connections: Iterable[Connection] | None = None, *, fast: bool = False,
    progress: str | None = None,
) -> Iterator[tuple[Connection, int, bytes]]:
    """``(connection, t_rec_ns, raw)`` of ``reader.messages(connections)``; a read failure is a :class:`BagError`.

    ``fast``: read a single-file MCAP bag with :func:`~ccf_ros.offline.mcap.fast_messages` (same messages, same
    order, same bytes), else through rosbags. ``progress``: a progress bar with this label on a terminal (stderr).
    Only the reading is guarded: what the caller does with a message (between two ``next``) is not.
    """
    conns = list(connections) if connections is not None else list(reader.connections)
    if progress is not None and sys.stderr.isatty():
        yield from _with_bar(read_messages(reader, path, conns, fast=fast), progress, sum(c.msgcount for c in conns))
        return
    try:
        it: Iterator[Any] | None = None
        if fast:
            from .mcap import fast_messages

            it = fast_messages(reader, conns)
        if it is None:
            it = reader.messages(connections=conns)
    except Exception as err:
        raise unreadable(path, err) from err
    while True:
        try:
            item = next(it)
        except StopIteration:
            return
        except Exception as err:  # rosbags (mcap, sqlite3, ROS 1 readers) raises several types
            raise unreadable(path, err) from err
        yield item


def _with_bar(items: Iterator[Any], label: str, total: int) -> Iterator[Any]:
    """``items``, counted on a progress bar (updated per 1000: a bar's update per message costs as much as reading)."""
    from tqdm import tqdm

    with tqdm(total=total, unit='msg', desc=label, mininterval=0.5) as bar:
        k = 0
        for k, item in enumerate(items, 1):
            if not k % 1000:
                bar.update(1000)
            yield item
        bar.update(k % 1000)


def deserialize(reader: AnyReader, raw: bytes | memoryview, msgtype: str, path: str | Path) -> Any:
    """``reader.deserialize(raw, msgtype)``; a message that does not decode is a :class:`BagError`."""
    try:
        return reader.deserialize(raw, msgtype)  # type: ignore[arg-type]  # rosbags reads memoryviews too
    except Exception as err:
        raise unreadable(path, err) from err


def ros1_to_cdr(store: Typestore, raw: bytes | memoryview, msgtype: str, path: str | Path) -> memoryview:
    """A ROS 1 message's bytes as CDR (with ``store``'s definition of ``msgtype``); one that does not decode is a
    :class:`BagError`."""
    try:
        return store.ros1_to_cdr(raw, msgtype)
    except Exception as err:  # rosbags' conversion of a message that does not decode
        raise unreadable(path, err) from err


#: What rosbags' writers raise when the file system refuses (full disk, permissions); anything else is a bug.
_WRITE_ERRORS = (OSError, sqlite3.Error)


class BagWriter:
    """A rosbags rosbag2 ``Writer`` whose file-system failures are :class:`BagError` (see :func:`open_writer`)."""

    def __init__(self, writer: Writer, path: Path) -> None:
        self.writer = writer
        self.path = path
        self._fast: tuple[Callable[[Connection, int, bytes | memoryview], None], Callable[[], None]] | None = None

    def add_connection(self, topic: str, msgtype: str, **kwargs: Any) -> Connection:
        try:
            return self.writer.add_connection(topic, msgtype, **kwargs)
        except _WRITE_ERRORS as err:
            raise self._error(err) from err

    def write(self, connection: Connection, t_ns: int, data: bytes | memoryview) -> None:
        try:
            self.writer.write(connection, t_ns, data)
        except _WRITE_ERRORS as err:
            raise self._error(err) from err

    @contextmanager
    def guarded(self) -> Iterator[Callable[[Connection, int, bytes | memoryview], None]]:
        """A ``write`` for a tight loop of writes under one guard instead of one per message: a file-system failure
        in the ``with`` body is a :class:`BagError` (keep other I/O out of the body).

        For MCAP it is :func:`~ccf_ros.offline.mcap.fast_writer`'s (the same bytes, without rosbags' per-message
        checks: write only to connections added with :meth:`add_connection`); the messages are in the bag when the
        ``with`` body ends."""
        if self._fast is None:
            from .mcap import fast_writer

            self._fast = fast_writer(self.writer)
        write, flush = self._fast
        try:
            yield write
            flush()
        except _WRITE_ERRORS as err:
            raise self._error(err) from err

    def _error(self, err: BaseException) -> BagError:
        return BagError(f'{self.path}: cannot write bag: {type(err).__name__}: {err}')


def _remove(path: Path) -> None:
    shutil.rmtree(path) if path.is_dir() and not path.is_symlink() else path.unlink()


def refuse_existing(path: Path, overwrite: bool, *, bag: bool = True) -> None:
    """:class:`BagError` if output ``path`` exists and may not be replaced (check before any slow work).

    With ``overwrite`` an existing output is replaced only if it is of the kind written: a bag (``bag``, a folder
    of ``metadata.yaml`` and storage files, or empty) or a file; never another folder, nor a file by a bag.
    """
    if not (path.exists() or path.is_symlink()):
        return
    if not overwrite:
        raise BagError(f'{path} exists; pass --overwrite to replace it')
    _check_replaceable(path, bag)


def _check_replaceable(path: Path, bag: bool) -> None:
    if path.is_symlink():
        return  # the link is replaced, not what it points to
    if path.is_dir():
        if not bag:
            raise BagError(f'{path} is a folder; refusing to replace it with a file (choose another output)')
        names = {p.name for p in path.iterdir()}
        if names and not ('metadata.yaml' in names and all(p.is_file() for p in path.iterdir())):
            raise BagError(f'{path} is a folder that is not a bag; refusing to replace it (choose another output)')
    elif bag and path.exists():
        raise BagError(f'{path} is a file, not a bag; refusing to replace it (choose another output)')


@contextmanager
def staged(path: str | Path, *, bag: bool = True) -> Iterator[Path]:
    """Where to write a new bag (or, ``bag=False``, a file) that becomes ``path`` only when complete: an error or
    Ctrl-C leaves no half bag. The one atomic-write helper of the offline tools.

    Yields ``.NAME.partial/NAME`` next to ``path`` (the storage file is named after the bag, ``NAME.mcap``); when
    the ``with`` body succeeds it replaces ``path`` (if that exists and is of the same kind, see
    :func:`refuse_existing`), otherwise the staging directory is removed.
    """
    path = Path(path)
    stage = path.with_name(f'.{path.name}.partial')
    if path.exists() or path.is_symlink():
        _check_replaceable(path, bag)  # before the stage exists: a refusal leaves nothing behind
    try:
        if stage.exists() or stage.is_symlink():
            _remove(stage)  # left over from a killed run
        stage.mkdir(parents=True)  # the output's folder too, if it does not exist yet
    except OSError as err:
        raise BagError(f'cannot create {stage}: {err.strerror}') from err
    try:
        yield stage / path.name
        if path.exists() or path.is_symlink():
            _remove(path)
        (stage / path.name).rename(path)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    stage.rmdir()


@contextmanager
def open_writer(path: str | Path, storage: str = 'mcap') -> Iterator[BagWriter]:
    """A new rosbag2 (version 9) at ``path`` in ``storage`` (``mcap`` or ``sqlite3``), closed on exit.

    On an exception in the ``with`` body the writer is aborted and the exception passes unchanged; the caller removes
    the half-written directory. Raises :class:`BagError` if the bag cannot be created, written or closed.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer, WriterError

    plugins = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}
    if storage not in plugins:
        raise BagError(f'unknown storage {storage!r} ({" or ".join(STORAGES)})')
    path = Path(path)
    try:
        writer = Writer(path, version=9, storage_plugin=plugins[storage])
        writer.open()
    except (WriterError, *_WRITE_ERRORS) as err:
        raise BagError(f'{path}: cannot create bag: {type(err).__name__}: {err}') from err
    try:
        yield BagWriter(writer, path)
    except BaseException:
        with suppress(Exception):
            writer.abort()
        raise
    try:
        writer.close()
    except _WRITE_ERRORS as err:
        with suppress(Exception):
            writer.abort()
        raise BagError(f'{path}: cannot write bag: {type(err).__name__}: {err}') from err


def connections_for(
    reader: AnyReader, topic: str, required: bool = True, msgtype: str | None = None
) -> list[Connection]:
    """Connections of ``topic``; :class:`BagError` listing the bag's topics if required and absent, or naming the
    type if ``msgtype`` is given and the topic has another."""
    conns = [c for c in reader.connections if c.topic == topic]
    if required and not conns:
        have = ', '.join(sorted({c.topic for c in reader.connections})) or 'none'
        raise BagError(f'topic {topic} not in bag (topics: {have})')
    for c in conns:
        if msgtype is not None and c.msgtype != msgtype:
            raise BagError(f'topic {topic} is {c.msgtype}, expected {msgtype}')
    return conns


IMU_TYPE = 'sensor_msgs/msg/Imu'
MAG_TYPE = 'sensor_msgs/msg/MagneticField'
#: The topics read when a bag has several of a type and none is named (imu_tools' names).
DEFAULT_IMU_TOPIC = '/imu/data_raw'
DEFAULT_MAG_TOPIC = '/imu/mag'


def detect_topics(
    reader: AnyReader, path: str | Path, imu_topic: str | None, mag_topic: str | None, no_mag: bool = False
) -> tuple[str, str | None, bool]:
    """The IMU and magnetometer topics to read, and whether the magnetometer topic is required (named by the user).

    A topic not named (None) is the bag's one topic of its type; of several, the default name if it is one of them,
    else a :class:`BagError` naming them. No magnetometer topic: :data:`DEFAULT_MAG_TOPIC`, which replay reads as
    absent (6-D with a warning). ``no_mag``: None.
    """

    def topics_of(msgtype: str) -> list[str]:
        return sorted({c.topic for c in reader.connections if c.msgtype == msgtype})

    if imu_topic is None:
        imus = topics_of(IMU_TYPE)
        if len(imus) == 1:
            imu_topic = imus[0]
        elif not imus:
            have = ', '.join(sorted({c.topic for c in reader.connections})) or 'none'
            raise BagError(f'{path}: no sensor_msgs/Imu topic in bag (topics: {have})')
        elif DEFAULT_IMU_TOPIC in imus:
            imu_topic = DEFAULT_IMU_TOPIC
        else:
            raise BagError(f'{path}: several sensor_msgs/Imu topics ({", ".join(imus)}): choose one with --imu-topic')
    if no_mag:
        return imu_topic, None, False
    if mag_topic is not None:
        return imu_topic, mag_topic, True
    mags = topics_of(MAG_TYPE)
    if len(mags) == 1:
        return imu_topic, mags[0], False
    if len(mags) > 1 and DEFAULT_MAG_TOPIC not in mags:
        raise BagError(f'{path}: several sensor_msgs/MagneticField topics ({", ".join(mags)}): choose one with '
                       '--mag-topic or pass --no-mag')
    return imu_topic, DEFAULT_MAG_TOPIC, False


def message_counts(path: str | Path) -> dict[str, int]:
    """Messages per topic of a bag (a topic without messages: 0; :class:`BagError` if it cannot be read)."""
    counts: dict[str, int] = {}
    with open_bag(path) as reader:
        for c in reader.connections:
            counts[c.topic] = counts.get(c.topic, 0) + c.msgcount
    return counts


def require_topic(path: str | Path, topic: str) -> None:
    """:class:`BagError` listing the bag's topics unless ``topic`` is one of them and has messages."""
    counts = message_counts(path)
    if topic not in counts:
        raise BagError(f'{path}: topic {topic} not in bag (topics: {", ".join(sorted(counts)) or "none"})')
    if not counts[topic]:
        raise BagError(f'{path}: no messages on {topic}')


def in_bag_order(reader: AnyReader, conns: Iterable[Connection]) -> list[Connection]:
    """``conns`` in the order of ``reader.connections``.

    rosbags' ROS 1 reader yields messages of equal receive time in the order of the connections it is given:
    in the bag's order, a magnetometer stamped like the IMU comes first if its connection does (as recorded),
    not after because the IMU topic was named first.
    """
    wanted = {id(c) for c in conns}
    return [c for c in reader.connections if id(c) in wanted]


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
    progress: str | None = None,
) -> ImuArrays:
    """Read all IMU samples (and paired magnetometer samples) of a bag into arrays (``progress``: a bar's label)."""
    pairer = MagPairer(timeout_s=mag_timeout_s)
    t, g, a, m = [], [], [], []
    nan3 = (np.nan, np.nan, np.nan)
    with open_bag(path) as reader:
        conns = connections_for(reader, imu_topic, msgtype='sensor_msgs/msg/Imu')
        if mag_topic:
            mag = connections_for(reader, mag_topic, required=False, msgtype='sensor_msgs/msg/MagneticField')
            conns = in_bag_order(reader, conns + mag)
        for conn, _, raw in read_messages(reader, path, conns, progress=progress):
            msg = deserialize(reader, raw, conn.msgtype, path)
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
        raise BagError(f'{msgtype} holds no orientation (use an Imu, PoseStamped, QuaternionStamped or Odometry topic)')
    return from_xyzw(o.x, o.y, o.z, o.w)


def read_topic(
    path: str | Path, topic: str, msgtype: str | None = None, progress: str | None = None
) -> Iterator[tuple[Connection, int, Any]]:
    """``(connection, t_rec_ns, message)`` of every message of ``topic`` (required; of type ``msgtype`` if given),
    deserialized; the bag is open while the caller iterates (``progress``: a bar's label, on a terminal)."""
    with open_bag(path) as reader:
        conns = connections_for(reader, topic, msgtype=msgtype)
        for conn, t_rec, raw in read_messages(reader, path, conns, progress=progress):
            yield conn, t_rec, deserialize(reader, raw, conn.msgtype, path)


def read_orientations(path: str | Path, topic: str, progress: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Header stamps ``(N,)`` s and orientations ``(N, 4)`` ``[w, x, y, z]`` of a topic (``progress``: a bar's label).

    An Imu message that marks its orientation unknown (``orientation_covariance[0] == -1``, as a driver's raw
    output does) gives NaN; :class:`BagError` if every message of the topic does (it holds no orientation).
    """
    t, q = [], []
    n_unknown = 0
    nan4 = (math.nan,) * 4
    for conn, _, msg in read_topic(path, topic, progress=progress):
        if conn.msgtype.endswith('/Imu') and msg.orientation_covariance[0] == -1.0:
            n_unknown += 1
            q.append(nan4)
        else:
            try:
                q.append(orientation_of(msg, conn.msgtype))
            except BagError as err:
                raise BagError(f'{path}: {topic}: {err}') from None
        t.append(stamp_s(msg.header))
    if t and n_unknown == len(t):
        raise BagError(f'{path}: every message on {topic} marks its orientation unknown (orientation_covariance[0] '
                       '= -1): it holds no orientation to score (the filter output is /imu/data)')
    return np.array(t, dtype=float), np.array(q, dtype=float).reshape(-1, 4)


def read_bools(path: str | Path, topic: str) -> tuple[np.ndarray, np.ndarray]:
    """Receive times ``(N,)`` s (bag time, std_msgs has no header) and values ``(N,)`` of a Bool topic."""
    t, v = [], []
    for _, t_rec, msg in read_topic(path, topic, 'std_msgs/msg/Bool'):
        t.append(t_rec * 1e-9)
        v.append(bool(msg.data))
    return np.array(t, dtype=float), np.array(v, dtype=bool)
