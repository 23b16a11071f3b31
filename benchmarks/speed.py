"""Speed ratios measured in one run (the machine is shared: absolute times are noisy, ratios less so).

1. ``ccf replay`` wall time vs a bare rosbags read -> deserialize -> serialize -> write of the same messages
   (IMU + magnetometer read, Imu + Vector3Stamped written per IMU sample), no filtering. Target <= 1.25.
2. Core ``update()`` cost per sample in CPython (quaternion CCF, 9-D) on the trial's first 20000 samples (the
   first 30 s rest), vs the paper's Euler form and an empty Python call.

Usage: python benchmarks/speed.py [BAG]  (default: a shared BROAD trial)
"""

from __future__ import annotations

import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ccf_ros.core import make_filter
from ccf_ros.engine import ImuEngine
from ccf_ros.offline.bagio import open_bag, read_imu_arrays, typestore
from ccf_ros.offline.replay import replay

BAG = Path(__file__).resolve().parents[2] / 'shared' / 'data' / 'broad' / '07_undisturbed_fast_rotation_B'


def bare_copy(src: Path, dst: Path) -> int:
    """Read IMU + mag, deserialize, and per IMU message serialize an Imu and a Vector3Stamped and write them."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    ts = typestore()
    V3S = ts.types['geometry_msgs/msg/Vector3Stamped']
    n = 0
    with open_bag(src) as reader, Writer(dst, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns = [c for c in reader.connections if c.topic in ('/imu/data_raw', '/imu/mag')]
        c_imu = w.add_connection('/imu/data', 'sensor_msgs/msg/Imu', typestore=ts)
        c_b = w.add_connection('/imu/gyro_bias', V3S.__msgtype__, typestore=ts)
        for conn, t, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic == '/imu/data_raw':
                w.write(c_imu, t, ts.serialize_cdr(msg, conn.msgtype))
                w.write(c_b, t, ts.serialize_cdr(V3S(header=msg.header, vector=msg.angular_velocity), V3S.__msgtype__))
                n += 1
    return n


def main() -> None:
    bag = Path(sys.argv[1]) if len(sys.argv) > 1 else BAG
    tmp = Path(tempfile.mkdtemp())
    bare, rep = [], []
    try:
        for i in range(5):  # interleaved, so both see the same machine load
            t0 = time.perf_counter()
            n = bare_copy(bag, tmp / f'bare{i}')
            bare.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            replay(bag, tmp / f'rep{i}', ImuEngine(make_filter()), progress=False)
            rep.append(time.perf_counter() - t0)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f'{bag.name}: {n} IMU samples')
    print(f'bare read/deserialize/serialize/write: {min(bare):.2f} s (best of 5)   replay: {min(rep):.2f} s')
    print(f'replay / bare = {min(rep) / min(bare):.3f}   (target <= 1.25)')

    imu = read_imu_arrays(bag)
    n = 20000
    t, g, a, m = (x[:n].tolist() for x in (imu.t_s, imu.gyr, imu.acc, imu.mag))

    def loop(f) -> float:
        u = f.update
        t0 = time.perf_counter()
        for i in range(n):
            u(t[i], g[i], a[i], m[i])
        return (time.perf_counter() - t0) / n * 1e6

    def empty(*_args) -> int:
        return 0

    class Empty:
        update = staticmethod(empty)

    # Best of 9 interleaved rounds: the minimum is the figure least inflated by the other users of the machine.
    res: dict[str, list[float]] = {'ccf': [], 'ccf_euler': [], 'empty call': []}
    for _ in range(9):
        res['ccf'].append(loop(make_filter()))
        res['ccf_euler'].append(loop(make_filter({'formulation': 'euler'})))
        res['empty call'].append(loop(Empty()))
    for k, v in res.items():
        print(f'core update {k:11s}: {np.min(v):5.2f} us/sample (best of 9), median {np.median(v):5.2f}')
    best = {k: float(np.min(v)) for k, v in res.items()}
    print(f'ccf update / euler update = {best["ccf"] / best["ccf_euler"]:.2f}   (target: ccf <= 4 us)')
    print(f'ccf update / empty call = {best["ccf"] / best["empty call"]:.1f}')


if __name__ == '__main__':
    main()
