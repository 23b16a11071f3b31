"""One bag of a fleet run, in a worker: engine + health (+ the output bag, + accuracy), a small result dict, and
the bag's result file written atomically. The only code that runs on Dask workers."""

from __future__ import annotations

import contextlib
import json
import math
import os
import threading
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..settings import MOTION_HINT_DEFAULT
from .health import HealthAccumulator, judge

__all__ = ['BagTimeout', 'FleetOptions', 'VersionMismatch', 'filter_metrics', 'process_bag', 'result_path', 'write_first']

#: Where a bag's result and output bag go, under the run's output folder.
BAGS_DIR = 'bags'
REFERENCE_TYPES = ('geometry_msgs/msg/PoseStamped', 'sensor_msgs/msg/Imu', 'geometry_msgs/msg/QuaternionStamped',
                   'nav_msgs/msg/Odometry')


class VersionMismatch(RuntimeError):
    """The worker runs another ccf_ros version than the driver (its results would not be the driver's)."""


class BagTimeout(RuntimeError):
    """The bag took longer than ``--task-timeout``."""


class _TimeUp(BaseException):
    """What the deadline's timer raises in the task's thread: not an ``Exception``, so no ``except Exception`` on
    the way (a read guard turning errors into :class:`BagError`) takes it for something else."""


@dataclass(frozen=True)
class FleetOptions:
    """What every task needs (picklable: sent to the workers)."""

    out: str  # the run's output folder (absolute)
    settings: dict[str, Any]  # the engine's merged settings (ccf_ros.cli.engine_settings)
    strict: bool
    version: str
    imu_topic: str | None = None
    mag_topic: str | None = None
    no_mag: bool = False
    motion_hint_topic: str | None = None  # resolved; None: none
    motion_hint: tuple[float, float, float] = MOTION_HINT_DEFAULT  # (speed m/s, turn rate rad/s, timeout s)
    write_bags: bool = False
    reference: str = '/ground_truth/pose'
    mask_topic: str = '/ground_truth/moving'
    task_timeout_s: float = 0.0  # 0: none
    #: seconds each bag is held back before it starts (tests: a bag slow enough to kill its worker mid-run); when
    #: set, each attempt also leaves a marker OUT/attempts/KEY.PID.RANDOM
    slow_bag_s: float = 0.0


def result_path(out: str | Path, key: str) -> Path:
    return Path(out) / BAGS_DIR / f'{key}.json'


def output_bag_path(out: str | Path, bag: str, key: str) -> Path:
    name = Path(bag).name.removesuffix('.mcap').removesuffix('.db3').removesuffix('.bag')
    return Path(out) / BAGS_DIR / f'{name}-{key[:10]}'


def _write_atomic(path: Path, text: str) -> None:
    """Write beside ``path`` under a name of this process, then rename: readers see the whole file or none."""
    tmp = path.with_name(f'.{path.name}.{os.getpid()}.tmp')
    try:
        tmp.write_text(text)
        tmp.replace(path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_first(path: Path, text: str) -> bool:
    """Like :func:`_write_atomic`, but only if ``path`` does not exist yet (a hard link fails then): when Dask runs a
    task twice (a worker lost after it finished, before its result was gathered; work stealing), the first complete
    result stays. Returns whether this one was written."""
    # (Unique across hosts sharing the folder: pids alone repeat.)
    tmp = path.with_name(f'.{path.name}.{uuid.uuid4().hex}.tmp')
    try:
        tmp.write_text(text)
        try:
            os.link(tmp, path)
        except FileExistsError:
            return False
        except OSError:
            # A file system without hard links (some SMB/FUSE mounts): a rename, last writer wins.
            if path.exists():
                return False
            tmp.replace(path)
        return True
    finally:
        tmp.unlink(missing_ok=True)


def _publish(new: Path, path: Path) -> None:
    """Rename the complete bag folder ``new`` to ``path`` atomically, replacing a bag there (an earlier run's, or
    another attempt's at the same key: the same messages). A folder cannot be renamed over a non-empty one, so the
    old one is first moved aside under a unique name and removed after."""
    import shutil

    for _ in range(5):  # (another attempt may publish between our two renames: then again)
        try:
            new.rename(path)
            return
        except OSError:
            if not path.exists():
                raise
        aside = path.with_name(f'.{path.name}.{uuid.uuid4().hex}.old.partial')
        with contextlib.suppress(FileNotFoundError):
            path.rename(aside)
        shutil.rmtree(aside, ignore_errors=True)
    raise OSError(f'cannot publish {path}: other attempts keep replacing it')


def filter_metrics(engine: Any) -> dict[str, float]:
    """The filter's figures at the end of a bag: NaN resets, restarts, gyro-only share, final bias and its σ."""
    f = engine.filter
    n = max(engine.n_in, 1)
    bias = f.gyro_bias
    sigma = getattr(f, 'gyro_bias_sigma_rad_s', math.nan)
    return {
        'filter_nonfinite_resets': float(engine.n_nonfinite_resets),
        'filter_restarts': float(engine.n_resets_jump),
        'filter_gyro_only_share': engine.n_no_acc / n,
        'filter_no_heading_share': engine.n_no_mag / n,
        'filter_skipped_share': sum(engine.skipped_by_reason().values()) / n,
        'filter_bias_x_rad_s': float(bias[0]), 'filter_bias_y_rad_s': float(bias[1]),
        'filter_bias_z_rad_s': float(bias[2]),
        'filter_bias_sigma_rad_s': float(sigma() if callable(sigma) else sigma),
    }


class _Deadline:
    """``--task-timeout`` by the clock, at no cost per sample: a timer thread raises :class:`_TimeUp` in the task's
    thread once ``timeout_s`` passed (``PyThreadState_SetAsyncExc``: delivered at the thread's next Python
    instruction, so a bag that hangs in Python code anywhere, reading included, ends too; a call blocked inside C,
    e.g. a read from a dead network mount, ends when that call returns). The task reports it as :class:`BagTimeout`.

    Use as a context manager around the bag's work only: leaving it disarms the timer under a lock, and an
    exception set but not yet delivered is withdrawn and raised here instead, so none escapes into the code after.
    """

    def __init__(self, timeout_s: float) -> None:
        self.timeout_s = timeout_s
        self._lock = threading.Lock()
        self._armed = False
        self._fired = False
        self._tid = threading.get_ident()
        self._timer: threading.Timer | None = None

    def __enter__(self) -> _Deadline:
        if self.timeout_s > 0:
            self._armed = True
            self._timer = threading.Timer(self.timeout_s, self._fire)
            self._timer.daemon = True
            self._timer.start()
        return self

    def _fire(self) -> None:
        with self._lock:
            if self._armed:
                self._fired = True
                _set_async_exc(self._tid, _TimeUp)

    def __exit__(self, *exc: object) -> None:
        if self._stop() and not isinstance(exc[1], _TimeUp):
            raise _TimeUp

    def disarm(self) -> None:
        """Stop the clock before work that must not be cut in the middle (publishing the output bag: moving the old
        one aside, renaming the new one in); raises :class:`_TimeUp` if the time was already up."""
        if self._stop():
            raise _TimeUp

    def _stop(self) -> bool:
        """Disarm; whether the time was up (an exception set but not yet delivered is withdrawn)."""
        if self._timer is None:
            return False
        self._timer.cancel()
        with self._lock:
            self._armed = False
            fired = self._fired
            if fired:
                _set_async_exc(self._tid, None)  # withdrawn if not delivered yet
        return fired

    def message(self) -> str:
        return f'took longer than the task timeout ({self.timeout_s:g} s)'


def _set_async_exc(tid: int, exc: type[BaseException] | None) -> None:
    import ctypes

    ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(tid), ctypes.py_object(exc) if exc else None)


def _health_bulk(reader: Any, bag: str, engine: Any, health: HealthAccumulator, conns: list[Any],
                 imu_ids: set[int]) -> bool:
    """The engine and ``health`` over a single-file MCAP bag a chunk at a time: fields decoded with numpy, the
    engine fed the same floats in the same order as message by message, ``health`` given arrays per chunk. False
    (nothing done) where the bag is not such a file; a chunk that is not all little-endian CDR is read message by
    message."""
    import numpy as np

    from ..messages.convert import stamp_s
    from ..offline.bagio import deserialize, unreadable
    from ..offline.mcap import McapError, fast_batches
    from ..offline.replay import decode_chunk, feed_chunk

    if not reader.is2:
        return False
    try:
        batches = fast_batches(reader, conns)
    except (McapError, OSError) as err:
        raise unreadable(bag, err) from err
    if batches is None:
        return False
    is_imu = np.array([c.id in imu_ids for c in conns])
    while True:
        try:
            cols = next(batches)
        except StopIteration:
            return True
        except Exception as err:  # a malformed chunk
            raise unreadable(bag, err) from err
        imu = is_imu[cols.owner]
        dec = decode_chunk(cols, imu)
        if dec is not None:
            _, ii, _, t_all, v1, v2 = dec
        else:  # message by message (rosbags deserializes each)
            t_all, v1, v2 = np.empty(len(imu)), np.zeros((len(imu), 3)), np.zeros((len(imu), 3))
            ii = np.flatnonzero(imu)
            for k, (a, b) in enumerate(zip(cols.start.tolist(), cols.end.tolist(), strict=True)):
                msg = deserialize(reader, cols.buf[a:b], conns[int(cols.owner[k])].msgtype, bag)
                t_all[k] = stamp_s(msg.header)
                v = msg.angular_velocity if imu[k] else msg.magnetic_field
                v1[k] = (v.x, v.y, v.z)
                if imu[k]:
                    v = msg.linear_acceleration
                    v2[k] = (v.x, v.y, v.z)
        feed_chunk(engine, imu, ii, t_all, v1, v2, health, answers=False)  # (no output bag: no answers)


def _health_only(bag: str, engine: Any, opts: FleetOptions, health: HealthAccumulator | None = None) -> list[str]:
    """The engine (and ``health``) over the bag without an output bag; returns warnings."""
    from ..errors import BagError
    from ..messages.cdr import LITTLE_ENDIAN_CDR, read_imu, read_mag
    from ..messages.convert import stamp_s
    from ..offline.bagio import connections_for, deserialize, detect_topics, in_bag_order, open_bag, read_messages
    from ..offline.replay import IMU, MAGNETIC_FIELD

    warnings: list[str] = []
    with open_bag(bag) as reader:
        imu_t, mag_t, required = detect_topics(reader, bag, opts.imu_topic, opts.mag_topic, opts.no_mag)
        imu_conns = connections_for(reader, imu_t, msgtype=IMU)
        mag_conns = connections_for(reader, mag_t, required=required, msgtype=MAGNETIC_FIELD) if mag_t else []
        if not sum(c.msgcount for c in imu_conns):
            raise BagError(f'{bag}: no messages on {imu_t}')
        if mag_t and not sum(c.msgcount for c in mag_conns) and getattr(engine.filter.params, 'use_mag', True):
            warnings.append(f'no {mag_t} in the bag: 6-D')
        imu_ids = {c.id for c in imu_conns}
        conns = in_bag_order(reader, imu_conns + mag_conns)
        if health is not None and _health_bulk(reader, bag, engine, health, conns, imu_ids):
            return warnings
        if health is not None:
            health.observe(engine)
        on_imu, on_mag = engine.on_imu, engine.on_mag
        ros2 = reader.is2
        for conn, _, raw in read_messages(reader, bag, conns, fast=True):
            if ros2 and raw[:2] == LITTLE_ENDIAN_CDR:
                if conn.id in imu_ids:
                    t, _, g, a = read_imu(raw)
                    on_imu(t, g, a)
                else:
                    t, f = read_mag(raw)
                    on_mag(t, f)
            else:
                msg = deserialize(reader, raw, conn.msgtype, bag)
                if conn.id in imu_ids:
                    gv, av = msg.angular_velocity, msg.linear_acceleration
                    on_imu(stamp_s(msg.header), (gv.x, gv.y, gv.z), (av.x, av.y, av.z))
                else:
                    fv = msg.magnetic_field
                    on_mag(stamp_s(msg.header), (fv.x, fv.y, fv.z))
    return warnings


def _has_reference(bag: str, topic: str) -> bool:
    """The bag has ``topic``, of a reference type, with messages."""
    from ..offline.bagio import open_bag

    with open_bag(bag) as reader:
        return any(c.topic == topic and c.msgtype in REFERENCE_TYPES and c.msgcount for c in reader.connections)


def _accuracy(out_bag: Path, bag: str, opts: FleetOptions) -> dict[str, Any]:
    """``ccf eval OUT --reference R --reference-bag BAG [--mask-topic M]``'s figures."""
    from ..offline.bagio import message_counts
    from ..offline.evaluate import evaluate, load_aligned

    mask = opts.mask_topic if opts.mask_topic and message_counts(bag).get(opts.mask_topic) else None
    s = evaluate(load_aligned(out_bag, opts.reference, reference_bag=bag, mask_topic=mask))
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in s.as_dict().items()}


def _run(bag: str, key: str, opts: FleetOptions, deadline: _Deadline) -> dict[str, Any]:
    from ..cli import make_engine
    from ..offline.replay import replay

    engine = make_engine(opts.settings, opts.strict)
    health = HealthAccumulator()
    if opts.slow_bag_s:
        # (Tests only.) One marker per attempt, OUT/attempts/KEY.PID.RANDOM: which worker process holds which bag,
        # and how many attempts a bag had.
        mark = Path(opts.out) / 'attempts' / f'{key}.{os.getpid()}.{uuid.uuid4().hex[:8]}'
        mark.parent.mkdir(parents=True, exist_ok=True)
        mark.touch()
        time.sleep(opts.slow_bag_s)
    has_ref = bool(opts.reference) and _has_reference(bag, opts.reference)
    record: dict[str, Any] = {}
    # The motion hint is read as replay reads it (its message path, which checks the topic): through replay, into a
    # staged bag kept only with --write-bags.
    if opts.write_bags or has_ref or opts.motion_hint_topic:
        import shutil

        out_bag = output_bag_path(opts.out, bag, key)
        # This attempt's own staging folder: another attempt at the same bag (a retry on another worker while a
        # lost one still runs) stages elsewhere. The bag is named as its final self inside (its storage file too).
        stage = out_bag.with_name(f'.{out_bag.name}.{uuid.uuid4().hex}.partial')
        try:
            stage.mkdir(parents=True)
            done = stage / out_bag.name
            summary = replay(bag, done, engine, imu_topic=opts.imu_topic, mag_topic=opts.mag_topic, detect=True,
                             no_mag=opts.no_mag, motion_hint_topic=opts.motion_hint_topic,
                             motion_hint=opts.motion_hint, overwrite=False, progress=False, health=health)
            warnings = summary.warnings
            if has_ref:
                record['accuracy'] = _accuracy(done, bag, opts)
            if opts.write_bags:
                deadline.disarm()
                _publish(done, out_bag)
                record['output'] = str(out_bag)
        finally:
            shutil.rmtree(stage, ignore_errors=True)
    else:
        warnings = _health_only(bag, engine, opts, health)
    metrics = health.result(filter_metrics(engine))
    health_level, flags = judge(metrics)
    return {'samples': int(metrics['samples']), 'health': health_level, 'flags': flags, 'metrics': metrics,
            'warnings': warnings, **record}


def process_bag(bag: str, key: str, opts: FleetOptions) -> dict[str, Any]:
    """Process one bag and write its result file (atomically); returns the result (small: no arrays).

    A bag that cannot be read, has no IMU topic or makes the filter raise gives ``status: failed`` with a one-line
    ``error``. Raises :class:`VersionMismatch` if this worker's ccf_ros is not the driver's.
    """
    from .keys import code_version

    if (mine := code_version()) != opts.version:
        raise VersionMismatch(f'worker has ccf_ros {mine}, the driver {opts.version}: install the same version '
                              '(the same code) on every worker')
    t0 = time.perf_counter()
    deadline = _Deadline(opts.task_timeout_s)
    try:
        try:
            with deadline:
                body = _run(bag, key, opts, deadline)
        except _TimeUp:
            raise BagTimeout(deadline.message()) from None
        result = {'bag': bag, 'key': key, 'status': 'ok', **body}
    except Exception as err:  # a bad bag, or the filter raising: this bag fails, the others go on
        msg = ' '.join(str(err).split()) or type(err).__name__
        result = {'bag': bag, 'key': key, 'status': 'failed', 'error': f'{type(err).__name__}: {msg}'}
    result['ccf_ros_version'] = mine
    result['wall_s'] = time.perf_counter() - t0
    path = result_path(opts.out, key)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not write_first(path, json.dumps(result, allow_nan=True)):
        try:
            first: dict[str, Any] = json.loads(path.read_text())
            return first  # exactly once: the result already recorded is the bag's
        except (OSError, ValueError):
            _write_atomic(path, json.dumps(result, allow_nan=True))  # an unreadable leftover: replaced
    return result
