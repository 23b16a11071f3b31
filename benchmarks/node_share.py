"""ccf_node with its own code timed (or untimed, or without it: ``CCF_SHARE_MODE``, below): the node_bench ``--cpu``
mode runs this instead of the installed ccf_node.

Thread CPU time (``time.thread_time_ns``) is summed over the node's per-message work (``CcfNode._mag``, ``_imu``: CDR
reading, the engine, patching the answer) minus what rclpy's ``publish`` takes inside it, and written to the file
named by ``CCF_SHARE_OUT`` at exit as ``ns_ours n_imu n_mag``, followed by one line per IMU message: its
``time.monotonic()`` after the callback and the ns of our code so far (so that node_bench takes our code's time over
exactly the messages of each chunk it measures the process's CPU time on). Everything else a message costs (DDS
threads, rclpy's take and executor) is the rest of the process's CPU time. The timing itself adds ~4 clock reads per
message, and counts about half of them as our code.
With ``CCF_SHARE_MODE=plain`` the node runs untimed, with ``null`` without our per-message code (the IMU bytes are
published back unchanged): ``node_bench.py --null`` takes our code's share as 1 - null / plain per round, from the
processes' CPU time alone, without a clock read in the node.
With ``CCF_PROFILE_OUT`` set, a cProfile of the whole node (executor included) is written to that file at exit.
With ``CCF_SPLIT_OUT`` set (``node_bench.py --split``), where our code's time goes: the wall time (perf counter) of
each step of the per-message path and of the timer, written to that file at exit as ``label ns calls`` lines. Its
own timers (~0.2 us each) add to the share measured in the same run.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

from ccf_ros import node as node_module
from ccf_ros.node import CcfNode

_clock = time.thread_time_ns
TOTAL = [0, 0]  # ns in our per-message code, ns of rclpy publish inside it
TIMELINE: list[tuple[float, int]] = []  # per IMU message: monotonic time after it, ns of our code so far


def _timed(method, slot, log=False):
    def wrapper(self, *args):
        t0 = _clock()
        try:
            return method(self, *args)
        finally:
            TOTAL[slot] += _clock() - t0
            if log:  # (the IMU callback: one time-line entry per IMU message)
                TIMELINE.append((time.monotonic(), TOTAL[0] - TOTAL[1]))

    return wrapper


def _timed_publish(pub) -> None:
    publish = pub.publish

    def timed(msg):
        t0 = _clock()
        publish(msg)
        TOTAL[1] += _clock() - t0

    pub.publish = timed


def _null_imu(self, data: bytes) -> None:
    """CCF_SHARE_MODE=null: what rclpy does for a message without our code: the IMU bytes published back unchanged."""
    self.pub_imu.publish(data)


def _null_mag(self, data: bytes) -> None:
    """CCF_SHARE_MODE=null: the magnetometer message is taken (by rclpy) and dropped."""


#: CCF_SHARE_MODE: 'timed' (default: our code timed, as above), 'plain' (ccf_node as installed, untimed: the
#: timers' own clock reads, ~1 us each on a VM, are not in its CPU) or 'null' (ccf_node without our per-message code:
#: the messages are taken, the IMU bytes published back). node_bench --null: our code = plain - null, per round.
MODE = os.environ.get('CCF_SHARE_MODE', 'timed')
if MODE == 'timed':
    CcfNode._mag = _timed(CcfNode._mag, 0)
    CcfNode._imu = _timed(CcfNode._imu, 0, log=True)
    _open = CcfNode._open_ccf

    def _open_timed(self):
        _open(self)
        for pub in (self.pub_imu, self.pub_bias):
            _timed_publish(pub)

    CcfNode._open_ccf = _open_timed
elif MODE == 'null':
    CcfNode._mag = _null_mag
    CcfNode._imu = _null_imu
elif MODE != 'plain':
    raise SystemExit(f'CCF_SHARE_MODE must be timed, plain or null, not {MODE!r}')

#: --split: label -> [ns, calls] of each step (wall time: a perf-counter read costs ~0.05-0.1 us, a CPU-clock read
#: ~0.6-1.1, a system call)
SPLIT: dict[str, list[int]] = {}


def _split(cls, name: str, label: str) -> None:
    """Time ``cls.name`` (a method or a staticmethod) into SPLIT[label] (inclusive of what it calls)."""
    raw = cls.__dict__.get(name)
    func = raw.__func__ if isinstance(raw, staticmethod) else getattr(cls, name)
    slot = SPLIT[label] = [0, 0]
    clock = time.perf_counter_ns

    def timed(*args):
        t0 = clock()
        try:
            return func(*args)
        finally:
            slot[0] += clock() - t0
            slot[1] += 1

    setattr(cls, name, staticmethod(timed) if isinstance(raw, staticmethod) else timed)


def _split_steps() -> None:
    from ccf_ros.core.ccf.filter import QuaternionCcf
    from ccf_ros.core.pairing import MagPairer
    from ccf_ros.engine import ImuEngine
    from ccf_ros.messages.paths import FastCdrPath
    from ccf_ros.node.stats import InputStats
    from ccf_ros.node.sync import ImuMagSync

    for cls, name, label in [
        (CcfNode, '_mag', 'magnetometer message (_mag, whole)'),
        (FastCdrPath, 'read_mag', '  read_mag (CDR bytes)'),
        (ImuEngine, 'on_mag', '  engine.on_mag'),
        (ImuMagSync, 'on_mag', '  sync.on_mag'),
        (CcfNode, '_imu', 'IMU message (_imu, whole, with rclpy publish)'),
        (FastCdrPath, 'read_imu', '  read_imu (CDR bytes)'),
        (InputStats, 'catch_up', '  stats.catch_up (rate, losses: per 32 IMU messages)'),
        (ImuMagSync, 'on_imu', '  sync.on_imu'),
        (ImuEngine, 'on_imu', '  engine.on_imu'),
        (MagPairer, 'get', '    pairer.get'),
        (QuaternionCcf, '_update_floats', '    filter update'),
        (QuaternionCcf, '_step', '      filter _step'),
        (ImuEngine, '_output', '    engine._output'),
        (FastCdrPath, 'answer', '  patch the answer'),
        (CcfNode, '_on_timer', 'timer (_on_timer, whole)'),
        (CcfNode, '_publish_diagnostics', '  diagnostics'),
        (CcfNode, '_check_endpoints', '  endpoint QoS check'),
    ]:
        _split(cls, name, label)


def main() -> None:
    stats = {}
    orig_init = CcfNode.__init__

    def init(self, *args, **kwargs):
        orig_init(self, *args, **kwargs)
        stats['node'] = self

    CcfNode.__init__ = init
    split_out = os.environ.get('CCF_SPLIT_OUT')
    if split_out:
        _split_steps()
    profile_out = os.environ.get('CCF_PROFILE_OUT')  # a cProfile of the whole node (where a wake-up's CPU goes)
    profiler = None
    if profile_out:
        import cProfile

        profiler = cProfile.Profile()
        profiler.enable()
    try:
        node_module.main()
    finally:
        if profiler is not None and profile_out:
            profiler.disable()
            profiler.dump_stats(profile_out)
        if split_out:
            Path(split_out).write_text(''.join(f'{label}\t{ns}\t{n}\n' for label, (ns, n) in SPLIT.items()))
        out = os.environ.get('CCF_SHARE_OUT')
        node = stats.get('node')
        if out and node is not None:
            Path(out).write_text(f'{TOTAL[0] - TOTAL[1]} {node.stats.n_imu} {node.stats.n_mag}\n'
                                 + ''.join(f'{t!r} {ns}\n' for t, ns in TIMELINE))


if __name__ == '__main__':
    main()
