"""``ccf fleet`` speed and memory: prints figures (ratios measured in this one run, interleaved).

1. ``ccf fleet run -j 2 --write-bags`` vs a sequential shell loop of ``ccf replay`` over the same >= 20 bags (the
   BROAD nine, linked, plus simulated bags; simulated only without ../shared), in ``--rounds`` rounds of both
   whose order alternates. Before it, the fixed cost of a fleet
   run: ``ccf fleet run -j 2`` on one bag vs ``ccf replay`` of it (CPU s).
2. Per core, in one process, on one bag (BROAD 02, else a simulated one): a bare rosbags read of the IMU and
   magnetometer records, the health-only task, the task with ``--write-bags``, ``replay()`` now and ``replay()`` on
   rosbags' own reader and writer (the path before the own MCAP reader), in samples/s.
3. Peak RSS (VmHWM) of a plain process running the health-only task (what one Dask worker's task holds, without
   what the Dask worker process itself holds besides) on a 2e6-sample bag and on a 2e5-sample one.

    .venv/bin/python benchmarks/fleet.py [--sim-bags 11] [--repeats 3] [--rounds 2] [--big 2000000] [--skip ...]
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BROAD = ROOT.parent.parent / 'shared' / 'data' / 'broad'
if not BROAD.exists():
    BROAD = Path('/work/shared/data/broad')
BIN = Path(sys.executable).parent


def _trials() -> list[Path]:
    return sorted(p for p in BROAD.iterdir() if (p / 'metadata.yaml').exists()) if BROAD.exists() else []


def make_bags(folder: Path, n_sim: int) -> list[Path]:
    from ccf_ros.offline.simulate import generate, write_bag

    folder.mkdir(parents=True, exist_ok=True)
    bags = []
    for t in _trials():
        (folder / t.name).symlink_to(t)
        bags.append(folder / t.name)
    n_sim = max(n_sim, 20 - len(bags))
    for i in range(n_sim):
        p = folder / f'sim{i:02d}'
        write_bag(generate(120.0, 286.0, 100 + i), p)
        bags.append(p)
    return bags


def fleet_vs_loop(bags: list[Path], work: Path, rounds: int = 2) -> None:
    n = 0
    from ccf_ros.offline.bagio import message_counts

    for b in bags:
        n += message_counts(b).get('/imu/data_raw', 0)
    import resource

    def cpu() -> float:
        r = resource.getrusage(resource.RUSAGE_CHILDREN)
        return r.ru_utime + r.ru_stime

    def loop(r: int) -> None:
        for b in bags:
            subprocess.run([str(BIN / 'ccf'), 'replay', str(b), '-o', str(work / f'loop{r}' / b.name), '--overwrite'],
                           check=True, capture_output=True)

    def fleet(r: int) -> None:
        out = subprocess.run([str(BIN / 'ccf'), 'fleet', 'run', str(bags[0].parent), '-o', str(work / f'fleet{r}'),
                              '-j', '2', '--write-bags', '--reference', '', '--quiet'], capture_output=True, text=True)
        assert out.returncode == 0, out.stdout + out.stderr

    # Interleaved: loop then fleet in even rounds, fleet then loop in odd ones (each into a new output folder), so
    # that neither always runs on a warmer page cache or a quieter machine.
    ratios = []
    for r in range(rounds):
        took = {}
        for name, fn in ((('loop', loop), ('fleet', fleet)) if r % 2 == 0 else (('fleet', fleet), ('loop', loop))):
            c0, t0 = cpu(), time.perf_counter()
            fn(r)
            took[name] = (time.perf_counter() - t0, cpu() - c0)
        (loop_s, loop_cpu), (fleet_s, fleet_cpu) = took['loop'], took['fleet']
        ratios.append(loop_s / fleet_s)
        print(f'round {r + 1}: {len(bags)} bags, {n} IMU samples: sequential ccf replay loop {loop_s:.1f} s wall '
              f'({loop_cpu:.1f} CPU s), ccf fleet run -j 2 --write-bags {fleet_s:.1f} s wall ({fleet_cpu:.1f} CPU s; '
              f'cluster start included): {loop_s / fleet_s:.2f}x faster; load average {os.getloadavg()[0]:.1f}',
              flush=True)
    print(f'fleet -j 2 vs the loop: {statistics.median(ratios):.2f}x (median of {rounds} interleaved rounds)')


def fixed_cost(bag: Path, work: Path) -> None:
    """What a fleet run costs beyond its bags: ``ccf fleet run -j 2`` on one bag vs ``ccf replay`` of it, CPU s of
    the child processes (cluster start and stop, version check, tables, report)."""
    import resource

    def cpu() -> float:
        r = resource.getrusage(resource.RUSAGE_CHILDREN)
        return r.ru_utime + r.ru_stime

    one = work / 'one_bag'
    one.mkdir()
    (one / bag.name).symlink_to(bag.resolve())
    c0 = cpu()
    subprocess.run([str(BIN / 'ccf'), 'replay', str(bag), '-o', str(work / 'one_replay')], check=True,
                   capture_output=True)
    c1 = cpu()
    subprocess.run([str(BIN / 'ccf'), 'fleet', 'run', str(one), '-o', str(work / 'one_fleet'), '-j', '2',
                    '--write-bags', '--reference', '', '--quiet'], check=True, capture_output=True)
    c2 = cpu()
    print(f'one bag ({bag.name}): ccf replay {c1 - c0:.1f} CPU s, ccf fleet run -j 2 --write-bags {c2 - c1:.1f} CPU s '
          f'(fixed cost of a fleet run {c2 - c1 - (c1 - c0):.1f} CPU s)')


def _bare_read(bag: Path) -> int:
    from ccf_ros.offline.bagio import open_bag

    n = 0
    with open_bag(bag) as reader:
        conns = [c for c in reader.connections if c.topic in ('/imu/data_raw', '/imu/mag')]
        for _ in reader.messages(connections=conns):
            n += 1
    return n // 2


def per_core(bag: Path, work: Path, repeats: int) -> None:
    import ccf_ros.offline.mcap as mcap
    from ccf_ros.cli import build_parser, engine_settings, make_engine
    from ccf_ros.fleet.keys import code_version
    from ccf_ros.fleet.task import FleetOptions, process_bag
    from ccf_ros.offline.replay import replay

    merged, strict = engine_settings(build_parser().parse_args(['fleet', 'run', 'x', '-o', 'y']))
    fast = mcap.fast_messages, mcap.fast_writer, mcap.fast_batches, mcap.record_writer

    def old_replay() -> int:
        mcap.fast_messages = lambda *a: None  # type: ignore[assignment]
        mcap.fast_writer = lambda w: (w.write, lambda: None)  # type: ignore[assignment]
        mcap.fast_batches = lambda *a: None  # type: ignore[assignment]
        mcap.record_writer = lambda w: None  # type: ignore[assignment]
        try:
            return replay(bag, work / 'old', make_engine(merged, strict), overwrite=True, progress=False).n_in
        finally:
            mcap.fast_messages, mcap.fast_writer, mcap.fast_batches, mcap.record_writer = fast

    def new_replay() -> int:
        return replay(bag, work / 'new', make_engine(merged, strict), overwrite=True, progress=False).n_in

    def task(write: bool) -> int:
        opts = FleetOptions(out=str(work / 'task'), settings=merged, strict=strict, version=code_version(),
                            write_bags=write, reference='')
        r = process_bag(str(bag), 'w' if write else 'h', opts)
        assert r['status'] == 'ok', r
        return int(r['samples'])

    runs = {'bare rosbags read (IMU+mag records)': lambda: _bare_read(bag),
            'ccf fleet task, health only': lambda: task(False),
            'ccf fleet task, --write-bags': lambda: task(True),
            'replay() now': new_replay,
            'replay() on rosbags reader+writer (before)': old_replay}
    # Per core: samples per CPU second of this process (the machine is shared: wall time measures the neighbours).
    rates: dict[str, list[float]] = {k: [] for k in runs}
    walls: dict[str, list[float]] = {k: [] for k in runs}
    for _ in range(repeats):
        for name, fn in runs.items():  # interleaved
            c0, t0 = time.process_time(), time.perf_counter()
            n = fn()
            rates[name].append(n / (time.process_time() - c0))
            walls[name].append(n / (time.perf_counter() - t0))
    bare = statistics.median(rates['bare rosbags read (IMU+mag records)'])
    print(f'per core on {bag.name} (median of {repeats}; samples per CPU second, and per wall second):')
    for name, r in rates.items():
        med = statistics.median(r)
        print(f'  {name:45s} {med:10,.0f} /CPU s {statistics.median(walls[name]):10,.0f} /wall s   '
              f'bare read / this = {bare / med:.2f}')
    now, before = (statistics.median(rates[k]) for k in ('replay() now', 'replay() on rosbags reader+writer (before)'))
    print(f'  replay now / before: {now / before:.2f}x')


def write_big_bag(path: Path, n: int, rate_hz: float = 200.0) -> None:
    """An IMU + magnetometer bag of ``n`` samples (rest, then slow rotations about z with noise), written with
    patched CDR templates (the simulator's message-by-message writer would take many minutes)."""
    from ccf_ros.messages.cdr import read_imu
    from ccf_ros.offline.bagio import open_writer, staged, typestore
    from ccf_ros.offline.mcap import fast_writer

    ts = typestore()
    T = ts.types
    hdr = T['std_msgs/msg/Header'](stamp=T['builtin_interfaces/msg/Time'](sec=0, nanosec=0), frame_id='imu_link')
    v0 = T['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=0.0)
    imu = bytearray(ts.serialize_cdr(T['sensor_msgs/msg/Imu'](
        header=hdr, orientation=T['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=np.array([-1.0] + [0.0] * 8), angular_velocity=v0, angular_velocity_covariance=np.zeros(9),
        linear_acceleration=v0, linear_acceleration_covariance=np.zeros(9)), 'sensor_msgs/msg/Imu'))
    mag = bytearray(ts.serialize_cdr(T['sensor_msgs/msg/MagneticField'](
        header=hdr, magnetic_field=v0, magnetic_field_covariance=np.zeros(9)), 'sensor_msgs/msg/MagneticField'))
    _, off, _, _ = read_imu(bytes(imu))
    moff = off  # same header: the field starts where the Imu's orientation does
    rng = np.random.default_rng(0)
    stamp = struct.Struct('<iI')
    f3 = struct.Struct('<3d')
    with staged(path) as tmp, open_writer(tmp) as w:
        c_mag = w.add_connection('/imu/mag', 'sensor_msgs/msg/MagneticField', typestore=ts)
        c_imu = w.add_connection('/imu/data_raw', 'sensor_msgs/msg/Imu', typestore=ts)
        write, flush = fast_writer(w.writer)
        block = 100_000
        for start in range(0, n, block):
            k = np.arange(start, min(start + block, n))
            t = 1.7e9 + k / rate_hz
            wz = np.where(k < 10 * rate_hz, 0.0, 0.5 * np.sin(2 * np.pi * 0.05 * k / rate_hz))
            yaw = np.cumsum(wz) / rate_hz
            gyr = np.c_[np.zeros_like(wz), np.zeros_like(wz), wz] + rng.normal(0, 0.005, (len(k), 3))
            acc = np.c_[np.zeros_like(wz), np.zeros_like(wz), np.full_like(wz, 9.81)] + rng.normal(0, 0.05, (len(k), 3))
            magv = np.c_[20e-6 * np.cos(yaw), -20e-6 * np.sin(yaw), np.full_like(wz, -40e-6)]
            ns = np.round(t * 1e9).astype(np.int64)
            for i in range(len(k)):
                tn = int(ns[i])
                stamp.pack_into(imu, 4, tn // 1_000_000_000, tn % 1_000_000_000)
                stamp.pack_into(mag, 4, tn // 1_000_000_000, tn % 1_000_000_000)
                f3.pack_into(mag, moff, *magv[i])
                f3.pack_into(imu, off + 104, *gyr[i])
                f3.pack_into(imu, off + 200, *acc[i])
                write(c_mag, tn, bytes(mag))
                write(c_imu, tn, bytes(imu))
            flush()


# The peak is VmHWM (/proc/self/status: the high-water mark of this process's own address space, new at exec), not
# getrusage's ru_maxrss: Linux carries the parent's peak into a child's ru_maxrss across fork and exec, so a child of
# this benchmark (which holds a large bag's arrays while it writes it) reported the benchmark's own ~135 MB.
RSS_SCRIPT = """
import sys
from ccf_ros.cli import build_parser, engine_settings
from ccf_ros.fleet.keys import code_version
from ccf_ros.fleet.task import FleetOptions, process_bag
merged, strict = engine_settings(build_parser().parse_args(['fleet', 'run', 'x', '-o', 'y']))
opts = FleetOptions(out=sys.argv[2], settings=merged, strict=strict, version=code_version(), reference='')
r = process_bag(sys.argv[1], 'rss-' + sys.argv[1].rstrip('/').rsplit('/', 1)[-1], opts)  # (a key per bag: exactly once)
assert r['status'] == 'ok', r
hwm = next(line for line in open('/proc/self/status') if line.startswith('VmHWM:'))
print(r['samples'], int(hwm.split()[1]) / 1024.0, r['wall_s'])
"""


def peak_rss(work: Path, big: int) -> None:
    for n in (big // 10, big):
        bag = work / f'big{n}'
        t0 = time.perf_counter()
        write_big_bag(bag, n)
        made = time.perf_counter() - t0
        out = subprocess.run([sys.executable, '-c', RSS_SCRIPT, str(bag), str(work / 'rss')], check=True,
                             capture_output=True, text=True).stdout.split()
        size = sum(f.stat().st_size for f in bag.iterdir()) / 1e6
        print(f'health-only task on a {int(out[0]):,}-sample bag ({size:.0f} MB, written in {made:.0f} s): peak RSS '
              f'{float(out[1]):.0f} MB, {int(out[0]) / float(out[2]):,.0f} samples/s')
        shutil.rmtree(bag)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--sim-bags', type=int, default=11)
    ap.add_argument('--repeats', type=int, default=3)
    ap.add_argument('--big', type=int, default=2_000_000)
    ap.add_argument('--rounds', type=int, default=2, help='interleaved rounds of the fleet vs loop comparison')
    ap.add_argument('--skip', default='', help='comma-separated parts to skip: fleet, core, rss')
    args = ap.parse_args()
    skip = set(args.skip.split(','))
    with tempfile.TemporaryDirectory(prefix='ccf_fleet_bench_') as tmp:
        work = Path(tmp)
        print(f'{os.cpu_count()} cores; BROAD {"found" if _trials() else "absent"}')
        if 'core' not in skip:
            trials = _trials()
            bag = trials[0] if trials else make_bags(work / 'one', 1)[-1]
            per_core(bag, work, args.repeats)
        if 'fleet' not in skip:
            bags = make_bags(work / 'bags', args.sim_bags)
            fixed_cost(bags[0], work)
            fleet_vs_loop(bags, work, args.rounds)
        if 'rss' not in skip:
            peak_rss(work, args.big)


if __name__ == '__main__':
    main()
