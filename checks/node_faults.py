"""Faults through the installed ccf_node over loopback DDS; prints what was sent, answered and reported.

1. A shared BROAD trial (first 60 s) with NaN/Inf gyro and accelerometer, zero accelerometer and magnetometer
   vectors, duplicated and backward stamps, a 30 s gap and 10 s of silent magnetometer; reliable QoS.
2. 10 s of the trial at 3x its rate (858 Hz) with the node's default sensor-data QoS (best effort, depth 50):
   whatever DDS drops must be reported by the node's diagnostics.

Usage: python checks/node_faults.py
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

from ccf_ros.domains import own_domain

os.environ['ROS_DOMAIN_ID'] = str(own_domain())
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'test'))

import numpy as np
from conftest import TRIAL, copy_bag

from ccf_ros.offline.live import run_live


def main() -> None:
    import conftest

    tmp = Path(tempfile.mkdtemp())
    short = copy_bag(TRIAL, tmp / 'short', stop_s=60.0)

    class Factory:
        def mktemp(self, name: str) -> Path:
            p = tmp / name
            p.mkdir()
            return p

    path, injected = conftest.faulty_trial.__wrapped__(short, Factory())
    res = run_live(path, rate=4.0)
    n_invalid = injected['nan_gyro'] + injected['inf_gyro'] + injected['dup'] + injected['back']
    print(f'faults: sent {res.n_imu_sent} IMU messages ({n_invalid} with non-finite gyro or bad stamps), '
          f'answered {len(res.t_s)} (expected {res.n_imu_sent - n_invalid}), NaN published '
          f'{int((~np.isfinite(res.quat)).any(axis=1).sum())}, exit code {res.exit_code}')
    print('  diagnostics:', {k: v for k, v in res.diagnostics.items() if k.startswith(('skipped', 'gyro-only',
                                                                                        'samples', 'resets'))})
    start = {}

    def motion_10s(topic, msg, t):
        start.setdefault('t', t)
        return [(msg, t)] if 45e9 < t - start['t'] <= 55e9 else []

    seg = copy_bag(TRIAL, tmp / 'seg', stop_s=56.0, edit=motion_10s)
    res = run_live(seg, rate=3.0, node_qos='best_effort')
    lost = res.n_imu_sent - len(res.t_s)
    print(f'3x rate (858 Hz), best-effort input: sent {res.n_imu_sent}, answered {len(res.t_s)}, lost {lost}; '
          f'node diagnostics: samples in {res.diagnostics.get("samples in")}, lost upstream (estimated) '
          f'{res.diagnostics.get("messages lost upstream (estimated)")}, level {res.diagnostics.get("level")} '
          f'"{res.diagnostics.get("message")}"; NaN {int((~np.isfinite(res.quat)).any(axis=1).sum())}, '
          f'exit code {res.exit_code}')


if __name__ == '__main__':
    main()
