"""Shared fixtures. DDS must stay on loopback: every rclpy use in tests runs with these variables."""

from __future__ import annotations

import os
import random
from pathlib import Path

import pytest

# Network rule: DDS traffic never leaves the loopback interface, and tests get a domain of their own.
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('ROS_DOMAIN_ID', str(random.Random(os.getpid()).randint(100, 200)))

SHARED = Path(__file__).resolve().parents[2] / 'shared' / 'data' / 'broad'
TRIAL = SHARED / '02_undisturbed_slow_rotation_B'


@pytest.fixture(scope='session')
def broad_trial() -> Path:
    """A real BROAD trial (rosbag2, mcap)."""
    if not TRIAL.exists():
        pytest.skip(f'shared BROAD data not found at {SHARED}')
    return TRIAL


def copy_bag(src: Path, dst: Path, *, stop_s: float | None = None, edit=None, storage: str = 'mcap') -> Path:
    """Copy (part of) a bag, letting ``edit(topic, msg, t_rec_ns) -> list[(msg, t_rec_ns)]`` change messages."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from ccf_ros.offline.bagio import open_bag, typestore

    ts = typestore()
    plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
    with open_bag(src) as reader, Writer(dst, version=9, storage_plugin=plugin) as w:
        out = {c.topic: w.add_connection(c.topic, c.msgtype, typestore=ts) for c in reader.connections}
        t_start = None
        for conn, t, raw in reader.messages():
            t_start = t if t_start is None else t_start
            if stop_s is not None and t - t_start > stop_s * 1e9:
                break
            msg = reader.deserialize(raw, conn.msgtype)
            items = edit(conn.topic, msg, t) if edit else [(msg, t)]
            for m, tt in items:
                w.write(out[conn.topic], tt, ts.serialize_cdr(m, conn.msgtype))
    return dst


@pytest.fixture(scope='session')
def short_trial(broad_trial: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The first 60 s of the real trial (rest, then motion)."""
    return copy_bag(broad_trial, tmp_path_factory.mktemp('short') / 'short', stop_s=60.0)
