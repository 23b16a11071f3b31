"""Shared fixtures. DDS must stay on loopback: every rclpy use in tests runs with these variables."""

from __future__ import annotations

import copy
import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from ccf_ros import domains as domains_module
from ccf_ros.domains import DOMAIN_LOCK_DIR
from ccf_ros.messages.convert import stamp_s

# Network rule: DDS traffic never leaves the loopback interface, and every test gets a domain of its own (see
# ros_domain below). ROS_DOMAIN_ID from the environment is not used: the fixture sets it per test.
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
#: The ROS domains tests may use, 'LO-HI' (inclusive; Fast DDS's ports allow 0-232). Several suites on one machine
#: (CI jobs, developers' clones) share the range: a lock file per domain keeps each domain to one test at a time.
DOMAINS_ENV = 'CCF_TEST_DOMAINS'
DEFAULT_DOMAINS = '100-199'
#: Longest wait for a free domain, s (every one held by other suites' tests).
DOMAIN_WAIT_S = 120.0


def domain_range(spec: str | None = None) -> range:
    """The domains of ``spec`` ('LO-HI' or one number; default: env CCF_TEST_DOMAINS, else 100-199)."""
    spec = spec if spec is not None else os.environ.get(DOMAINS_ENV, DEFAULT_DOMAINS)
    lo_s, _, hi_s = spec.strip().partition('-')
    try:
        lo, hi = int(lo_s), int(hi_s or lo_s)
    except ValueError:
        raise pytest.UsageError(f'{DOMAINS_ENV} must be LO-HI (e.g. 150-199), got {spec!r}') from None
    if not 0 <= lo <= hi <= 232:
        raise pytest.UsageError(f'{DOMAINS_ENV} must lie within 0-232 with LO <= HI, got {spec!r}')
    return range(lo, hi + 1)


def acquire_domain(domains: range, wait_s: float = DOMAIN_WAIT_S, lock_dir: Path = DOMAIN_LOCK_DIR) -> tuple[int, int]:
    """Lock a free domain of ``domains`` (ccf_ros.domains: the demo, benchmarks and checks lock theirs alike)."""
    try:
        return domains_module.acquire_domain(domains, wait_s, lock_dir)
    except RuntimeError as err:
        raise RuntimeError(f'{err} (set {DOMAINS_ENV} to a wider or other range)') from None


@pytest.fixture(autouse=True)
def ros_domain(monkeypatch: pytest.MonkeyPatch) -> Iterator[int]:
    """A ROS domain of this test's own, in ROS_DOMAIN_ID for it and every process it starts: no other test of
    this or any parallel suite (using the same lock directory) is on it while it runs."""
    domain, fd = acquire_domain(domain_range())
    monkeypatch.setenv('ROS_DOMAIN_ID', str(domain))
    try:
        yield domain
    finally:
        os.close(fd)

SHARED = Path(__file__).resolve().parents[2] / 'shared' / 'data' / 'broad'
TRIAL = SHARED / '02_undisturbed_slow_rotation_B'
#: CI sets this: there the shared data must be present, and a missing folder fails the run instead of skipping.
REQUIRE_SHARED = os.environ.get('CCF_REQUIRE_SHARED', '') not in ('', '0')


def need_shared(path: Path = SHARED) -> Path:
    """``path`` inside the shared BROAD data; skip (a clone without ../shared) or fail (CI) when it is absent."""
    if not path.exists():
        message = f'shared BROAD data not found at {path}'
        if REQUIRE_SHARED:
            pytest.fail(message + ' (CCF_REQUIRE_SHARED is set)')
        pytest.skip(message)
    return path


@pytest.fixture
def context(ros_domain: int):
    """An rclpy context of its own on this test's domain (loopback only, see above), shut down afterwards."""
    rclpy = pytest.importorskip('rclpy')
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=ros_domain)
    yield ctx
    rclpy.try_shutdown(context=ctx)


@pytest.fixture(scope='session')
def broad_trial() -> Path:
    """A real BROAD trial (rosbag2, mcap)."""
    return need_shared(TRIAL)


@pytest.fixture(scope='session')
def sim_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """60 s of simulated hand-held motion at 286 Hz in the BROAD topic layout (5 s rest first), made with
    ``ccf simulate``: the pipeline, node and fault tests run on it everywhere, with or without ../shared."""
    from ccf_ros.cli import main as ccf

    path = tmp_path_factory.mktemp('sim') / 'sim'
    assert ccf(['simulate', '-o', str(path), '--duration', '60', '--rate', '286', '--seed', '11']) == 0
    return path


def copy_bag(src: Path, dst: Path, *, stop_s: float | None = None, edit=None, storage: str = 'mcap',
             little_endian=None) -> Path:
    """Copy (part of) a bag, letting ``edit(topic, msg, t_rec_ns) -> list[(msg, t_rec_ns)]`` change messages;
    ``little_endian(k) -> bool``: the byte order of the k-th message read (None: little-endian CDR throughout)."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from ccf_ros.offline.bagio import open_bag, typestore

    ts = typestore()
    plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
    with open_bag(src) as reader, Writer(dst, version=9, storage_plugin=plugin) as w:
        out = {c.topic: w.add_connection(c.topic, c.msgtype, typestore=ts) for c in reader.connections}
        t_start = None
        for k, (conn, t, raw) in enumerate(reader.messages()):
            t_start = t if t_start is None else t_start
            if stop_s is not None and t - t_start > stop_s * 1e9:
                break
            msg = reader.deserialize(raw, conn.msgtype)
            items = edit(conn.topic, msg, t) if edit else [(msg, t)]
            little = little_endian(k) if little_endian else True
            for m, tt in items:
                w.write(out[conn.topic], tt, ts.serialize_cdr(m, conn.msgtype, little_endian=little))
    return dst


def with_mag_distortion(src: Path, dst: Path, offset_t, matrix=None, topic: str = '/imu/mag') -> Path:
    """Copy of bag ``src`` whose magnetometer reads ``matrix @ m + offset_t`` (T; ``matrix`` None: the identity),
    as a hard-/soft-iron distortion on the robot would give."""
    import numpy as np

    b = np.asarray(offset_t, dtype=float)
    w = None if matrix is None else np.asarray(matrix, dtype=float)

    def edit(t_topic, msg, t):
        if t_topic == topic:
            f = msg.magnetic_field
            v = np.array([f.x, f.y, f.z])
            f.x, f.y, f.z = (v if w is None else w @ v) + b
        return [(msg, t)]

    return copy_bag(src, dst, edit=edit)


@pytest.fixture(scope='session')
def short_trial(broad_trial: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The first 60 s of the real trial (rest, then motion)."""
    return copy_bag(broad_trial, tmp_path_factory.mktemp('short') / 'short', stop_s=60.0)


def _stamp(msg, t_s):
    """Set a message's header stamp to ``t_s`` (s)."""
    msg.header.stamp.sec = int(t_s)
    msg.header.stamp.nanosec = int(round((t_s - int(t_s)) * 1e9))


def make_faulty(src: Path, dst: Path) -> tuple[Path, dict[str, int]]:  # noqa: C901 - one list of faults, read top down
    """``src`` with NaN/Inf, zero vectors, corrupted messages (every field NaN; finite but absurd values: a gyro of
    1e200 rad/s, an accelerometer of 1e150 m/s²), duplicated and backward stamps (one of them a copy with a zero
    accelerometer), a lone stamp 100 s ahead, a 30 s gap and 10 s of silent magnetometer injected; returns the bag
    and the counts of injected invalid samples (``bad_gyro``, ``bad_stamp``: those skipped for their gyro, stamp)."""
    k = {'imu': 0, 'mag': 0}
    injected = {'nan_gyro': 0, 'inf_gyro': 0, 'huge_gyro': 0, 'all_nan': 0, 'dup': 0, 'back': 0, 'ahead': 0}
    gap_s = 30.0

    def edit(topic, msg, t):  # noqa: C901 - the same list of faults
        if topic == '/imu/data_raw':
            i = k['imu']
            k['imu'] += 1
            st = stamp_s(msg.header)
            if i > 10000:  # 30 s gap after ~35 s
                _stamp(msg, st + gap_s)
                t += int(gap_s * 1e9)
            if i in (7000, 10001):
                # Skipped: a lone stamp 100 s ahead (undone by the next sample) and the first sample after the gap
                # (a stamp that far ahead is taken as a new timeline once the next sample confirms it).
                injected['ahead'] += 1
                if i == 7000:
                    _stamp(msg, st + 100.0)
            if i % 997 == 5:
                msg.angular_velocity.x = float('nan')
                injected['nan_gyro'] += 1
            elif i % 1009 == 7:
                msg.angular_velocity.z = float('inf')
                injected['inf_gyro'] += 1
            elif i % 1013 == 8:  # finite, but its square overflows
                msg.angular_velocity.y = 1e200
                injected['huge_gyro'] += 1
            elif i % 991 == 6:  # a sensor read error: every field NaN
                for v in (msg.angular_velocity, msg.linear_acceleration):
                    v.x = v.y = v.z = float('nan')
                injected['all_nan'] += 1
            elif i % 499 == 3:
                msg.linear_acceleration.x = msg.linear_acceleration.y = msg.linear_acceleration.z = 0.0
            elif i % 503 == 4:
                msg.linear_acceleration.y = float('nan')
            elif i % 1021 == 9:  # finite, and its square too: not a specific force
                msg.linear_acceleration.z = 1e150
            if i % 701 == 11:
                injected['dup'] += 1
                dup = copy.deepcopy(msg)
                if injected['dup'] % 2:  # a repeated stamp whose accelerometer is broken
                    dup.linear_acceleration.x = dup.linear_acceleration.y = dup.linear_acceleration.z = 0.0
                return [(msg, t), (dup, t)]
            if i % 809 == 13:
                injected['back'] += 1
                back = copy.deepcopy(msg)
                _stamp(back, st - 0.5)
                return [(msg, t), (back, t)]
            return [(msg, t)]
        if topic == '/imu/mag':
            j = k['mag']
            k['mag'] += 1
            if 13000 < j < 15860:  # 10 s of silent magnetometer
                return []
            if j > 10000:
                st = stamp_s(msg.header)
                _stamp(msg, st + gap_s)
                t += int(gap_s * 1e9)
            if j % 401 == 9:
                msg.magnetic_field.x = msg.magnetic_field.y = msg.magnetic_field.z = 0.0
            elif j % 409 == 10:
                msg.magnetic_field.z = float('-inf')
            return [(msg, t)]
        if topic == '/ground_truth/pose' and k['imu'] > 10000:
            st = stamp_s(msg.header)
            _stamp(msg, st + gap_s)
            return [(msg, t + int(gap_s * 1e9))]
        return [(msg, t)]

    path = copy_bag(src, dst, edit=edit)
    injected['bad_gyro'] = injected['nan_gyro'] + injected['inf_gyro'] + injected['huge_gyro'] + injected['all_nan']
    injected['bad_stamp'] = injected['dup'] + injected['back'] + injected['ahead']
    return path, injected


@pytest.fixture(scope='module')
def faulty_trial(short_trial: Path, tmp_path_factory) -> tuple[Path, dict[str, int]]:
    """The real trial with faults injected (see :func:`make_faulty`)."""
    return make_faulty(short_trial, tmp_path_factory.mktemp('faulty') / 'faulty')


@pytest.fixture(scope='module')
def faulty_sim(sim_bag: Path, tmp_path_factory) -> tuple[Path, dict[str, int]]:
    """The simulated bag with the same faults injected (runs without ../shared)."""
    return make_faulty(sim_bag, tmp_path_factory.mktemp('faulty_sim') / 'faulty')
