"""ccf_node vs a pass-through rclpy node, measured in the same run over loopback DDS (separate processes).

1. Throughput: IMU (+ magnetometer) published with sensor-data QoS at increasing rates for 2 s each; the highest
   rate at which every message came back on imu/data. Target: ccf_node >= 0.9 x pass-through.
2. Latency at 1 kHz: publish -> receive on imu/data, p50/p99. Target: ccf_node's p99 <= 1.2 x pass-through's.
3. A BROAD trial played at 286 Hz through ccf_node: every message answered, orientations vs `ccf replay` (1e-3 rad),
   gyro_bias published.

Usage: python benchmarks/node_bench.py  (sets ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and its own ROS_DOMAIN_ID)
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
# A domain of this run's own; child processes (spawned, re-importing this file) inherit the same one.
os.environ.setdefault('CCF_BENCH_DOMAIN_ID', str(random.randint(100, 200)))
os.environ['ROS_DOMAIN_ID'] = os.environ['CCF_BENCH_DOMAIN_ID']

import numpy as np  # noqa: E402
import rclpy  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data  # noqa: E402
from sensor_msgs.msg import Imu, MagneticField  # noqa: E402

from ccf_ros.offline.live import node_command  # noqa: E402

HERE = Path(__file__).resolve().parent
BROAD = HERE.parents[1] / 'shared' / 'data' / 'broad' / '07_undisturbed_fast_rotation_B'


def recorder(conn) -> None:
    """Child process: record (stamp_ns -> receive time) of imu/data; answer 'get' with the dict, 'stop' to end."""
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node(f'bench_rec_{os.getpid()}', context=ctx)
    recv: dict[int, float] = {}
    def on_out(msg: Imu) -> None:
        recv[msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec] = time.perf_counter()

    qos = QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE)
    # Only imu/data: the probe must do the same work for both nodes, or its own queue skews their latencies.
    node.create_subscription(Imu, 'imu/data', on_out, qos)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    conn.send('ready')
    while True:
        ex.spin_once(timeout_sec=0.01)
        if conn.poll():
            cmd = conn.recv()
            if cmd == 'get':
                conn.send(dict(recv))
            elif cmd == 'stop':
                break
    ex.shutdown()
    node.destroy_node()
    rclpy.try_shutdown(context=ctx)


class Rig:
    """Feeder in this process, recorder in a child process, the node under test in a subprocess."""

    def __init__(self, cmd: list[str]) -> None:
        import multiprocessing as mp

        self.proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        self.conn, child = mp.get_context('spawn').Pipe()
        self.rec = mp.get_context('spawn').Process(target=recorder, args=(child,), daemon=True)
        self.rec.start()
        assert self.conn.recv() == 'ready'
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx)
        self.node = rclpy.create_node(f'bench_{random.randint(0, 1 << 30)}', context=self.ctx)
        self.pub_imu = self.node.create_publisher(Imu, 'imu/data_raw', qos_profile_sensor_data)
        self.pub_mag = self.node.create_publisher(MagneticField, 'imu/mag', qos_profile_sensor_data)
        deadline = time.time() + 30
        while time.time() < deadline and (self.node.count_subscribers('imu/data_raw') == 0
                                          or self.node.count_subscribers('imu/data') == 0):
            time.sleep(0.05)
        time.sleep(1.0)

    def received(self) -> dict[int, float]:
        self.conn.send('get')
        return self.conn.recv()

    def send(self, rate_hz: float, duration_s: float, t_offset_ns: int) -> dict[int, float]:
        """Publish IMU + magnetometer pairs at ``rate_hz``; returns stamp -> send time."""
        imu, mag = Imu(), MagneticField()
        imu.linear_acceleration.z = 9.81
        imu.angular_velocity.x = 0.01
        mag.magnetic_field.y, mag.magnetic_field.z = 2e-5, -4e-5
        sent: dict[int, float] = {}
        n = int(rate_hz * duration_s)
        period = 1.0 / rate_hz
        t0 = time.perf_counter()
        for k in range(n):
            due = t0 + k * period
            ahead = due - time.perf_counter()
            if ahead > 0:
                time.sleep(ahead)
            stamp = t_offset_ns + int(k * period * 1e9)
            for m in (mag, imu):
                m.header.stamp.sec, m.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
            self.pub_mag.publish(mag)
            sent[stamp] = time.perf_counter()
            self.pub_imu.publish(imu)
        time.sleep(1.0)
        return sent

    def close(self) -> int | None:
        self.proc.send_signal(signal.SIGINT)
        try:
            code = self.proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            code = None
        self.conn.send('stop')
        self.rec.join(timeout=10)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)
        return code


def throughput(cmd: list[str], rates: list[float]) -> tuple[float, int | None]:
    """Highest rate (Hz) at which every IMU message came back; a rate passes if one of two tries is lossless."""
    rig = Rig(cmd)
    best = 0.0
    offset = 1_700_000_000 * 10**9
    try:
        for rate in rates:
            for _ in range(2):
                sent = rig.send(rate, 2.0, offset)
                recv = rig.received()
                got = sum(1 for s in sent if s in recv)
                offset += 10 * 10**9
                print(f'    {rate:6.0f} Hz: {got}/{len(sent)} answered', flush=True)
                if got == len(sent):
                    break
            if got < len(sent):
                break
            best = rate
    finally:
        code = rig.close()
    return best, code


def latency(cmd: list[str]) -> np.ndarray:
    """Publish -> imu/data latencies (ms) of 3 s at 1 kHz."""
    rig = Rig(cmd)
    try:
        sent = rig.send(1000.0, 3.0, 1_800_000_000 * 10**9)
        recv = rig.received()
    finally:
        rig.close()
    return np.array([recv[s] - t for s, t in sent.items() if s in recv]) * 1e3


def main() -> None:
    rates = [250, 500, 1000, 1500, 2000, 2500, 3000, 4000, 5000, 6000]
    cmds = {'pass-through': [sys.executable, str(HERE / 'passthrough_node.py')],
            'ccf_node': node_command() + ['--ros-args', '--log-level', 'error']}
    best = {}
    for label, cmd in cmds.items():
        print(f'{label} throughput:', flush=True)
        best[label], code = throughput(cmd, rates)
        print(f'  exit code {code}')
    # Latency: interleaved rounds, so that both nodes see the same machine load; medians of the per-round p99.
    p50: dict[str, list[float]] = {k: [] for k in cmds}
    p99: dict[str, list[float]] = {k: [] for k in cmds}
    for r in range(3):
        for label, cmd in cmds.items():
            lat = latency(cmd)
            p50[label].append(float(np.percentile(lat, 50)))
            p99[label].append(float(np.percentile(lat, 99)))
            print(f'  round {r + 1} {label:12s}: p50 {p50[label][-1]:.3f} ms, p99 {p99[label][-1]:.3f} ms '
                  f'({len(lat)}/3000 answered)', flush=True)
    print()
    for label in cmds:
        print(f'{label:12s}: highest rate without loss {best[label]:6.0f} Hz; latency at 1 kHz median p50 '
              f'{np.median(p50[label]):.3f} ms, median p99 {np.median(p99[label]):.3f} ms')
    print(f'throughput ratio ccf_node / pass-through = {best["ccf_node"] / best["pass-through"]:.2f}   (target >= 0.9)')
    ratio = np.median(p99['ccf_node']) / np.median(p99['pass-through'])
    print(f'latency p99 ratio ccf_node / pass-through (medians of 3 interleaved rounds) = {ratio:.2f}   (target <= 1.2)')
    if BROAD.exists():
        broad_through_node()


def broad_through_node() -> None:
    """A BROAD trial at 286 Hz through the installed ccf_node vs the offline engine on the same samples."""
    from ccf_ros.core import make_filter
    from ccf_ros.engine import ImuEngine
    from ccf_ros.offline.bagio import read_imu_arrays
    from ccf_ros.offline.evaluate import align
    from ccf_ros.offline.live import run_live

    res = run_live(BROAD, rate=1.0)
    imu = read_imu_arrays(BROAD)
    eng = ImuEngine(make_filter())
    ref = []
    for t, g, a, m in zip(imu.t_s.tolist(), imu.gyr.tolist(), imu.acc.tolist(), imu.mag.tolist(), strict=True):
        if np.isfinite(m[0]):
            eng.on_mag(t, tuple(m))
        o = eng.on_imu(t, tuple(g), tuple(a))
        ref.append((o.orientation_xyzw[3], *o.orientation_xyzw[:3]) if o else (np.nan,) * 4)
    ref = np.array(ref)
    print(f'  (reference: {len(ref)} samples through the same engine, magnetometer paired by stamp)')
    q = align(res.t_s, res.quat, imu.t_s, ref)
    d = 2 * np.arccos(np.clip(np.abs(np.sum(q * ref, axis=1)), 0, 1))
    print(f'\nBROAD {BROAD.name} at 286 Hz through ccf_node: {len(res.t_s)}/{res.n_imu_sent} answered, '
          f'NaN {int(np.isnan(res.quat).any(axis=1).sum())}, max |node - replay| {np.nanmax(d):.2e} rad, '
          f'exit code {res.exit_code}')


if __name__ == '__main__':
    main()
