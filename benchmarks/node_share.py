"""ccf_node with its own code timed: the node_bench ``--cpu`` mode runs this instead of the installed ccf_node.

Thread CPU time (``time.thread_time_ns``) is summed over the node's per-message work (``CcfNode._mag``, ``_imu``: CDR
reading, the engine, patching the answer) minus what rclpy's ``publish`` takes inside it, and written to the file
named by ``CCF_SHARE_OUT`` at exit as ``ns_ours n_imu n_mag``, followed by one line per IMU message: its
``time.monotonic()`` after the callback and the ns of our code so far (so that node_bench takes our code's time over
exactly the messages of each chunk it measures the process's CPU time on). Everything else a message costs (DDS
threads, rclpy's take and executor) is the rest of the process's CPU time. The timing itself adds ~4 clock reads per
message.
With ``CCF_PROFILE_OUT`` set, a cProfile of the whole node (executor included) is written to that file at exit.
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


CcfNode._mag = _timed(CcfNode._mag, 0)
CcfNode._imu = _timed(CcfNode._imu, 0, log=True)
_open = CcfNode._open_ccf


def _open_timed(self):
    _open(self)
    for pub in (self.pub_imu, self.pub_bias):
        _timed_publish(pub)


CcfNode._open_ccf = _open_timed


def main() -> None:
    stats = {}
    orig_init = CcfNode.__init__

    def init(self, *args, **kwargs):
        orig_init(self, *args, **kwargs)
        stats['node'] = self

    CcfNode.__init__ = init
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
        out = os.environ.get('CCF_SHARE_OUT')
        node = stats.get('node')
        if out and node is not None:
            Path(out).write_text(f'{TOTAL[0] - TOTAL[1]} {node.stats.n_imu} {node.stats.n_mag}\n'
                                 + ''.join(f'{t!r} {ns}\n' for t, ns in TIMELINE))


if __name__ == '__main__':
    main()
