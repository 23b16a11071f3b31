"""ccf_node vs a pass-through rclpy node of identical QoS, measured in the same run over loopback DDS.

Both nodes run for the whole benchmark, each in a namespace of its own (``/pt``, ``/ccf``), as subprocesses: the
installed ``ccf_node`` with its defaults, and ``passthrough_node.py``, which deserializes and serializes every message
the plain rclpy way. This process publishes IMU (+ magnetometer) messages, pre-serialized, with the nodes' own input
QoS (best effort, depth 50, sensor-data durability: one depth everywhere); a recorder child process takes imu/data
serialized (it is never the bottleneck). Measurements alternate between the nodes at every step (interleaved: both
see the same machine load, which on a shared machine changes by the second).

1. Throughput: a ladder of input rates, 2 s each, each rate tried on both nodes before the next; per node and round,
   the highest rate at which every IMU message came back on imu/data (a rate passes if one of two tries is
   loss-free). Target: ccf_node >= 1.0 x pass-through.
2. Latency at 1 kHz, publish -> receive on imu/data, in 1 s chunks alternating between the nodes (ABBA), p50/p99
   over all chunks, and the node's CPU time per message (user + system of its process, all threads). Target:
   ccf_node's p99 <= 1.2 x pass-through's.
3. The same with the magnetometer at 1/4 of the IMU rate on the same clock (its stamps = every 4th IMU stamp): the
   node must not hold IMU samples for it. Target: p50 and p99 within 1.5 x (+0.5 ms) of the full-rate run.
4. With ``--broad`` (and the shared data present): a BROAD trial at 286 Hz through ccf_node vs the offline engine.

5. With ``--cpu``, instead of 1-4: CPU time per message of ccf_node and of two identical pass-through nodes at
   200, 400 and 1000 Hz (magnetometer in lock-step), CPU from the scheduler's nanosecond counts
   (``/proc/PID/task/*/schedstat``), in rounds of 2 s chunks (pass-through, ccf_node, pass-through 2, then reversed);
   per round ccf_node / the mean of the two pass-throughs and the A/A ratio pass-through 2 / pass-through (the
   measurement's own resolution), printed as median, IQR and min-max over the rounds; and ccf_node's own code's
   share of its CPU time per message (``node_share.py``: thread CPU time of the node's per-message code, rclpy's
   publish excluded). Targets: ccf_node <= 0.8 x pass-through per message, our code <= 25 % of ccf_node's.
   With ``--against PYTHON`` also the node of another install (``node_share.py`` run by that Python, e.g. an older
   checkout's venv with ccf_ros installed from it) in the same rounds, between the same pass-through chunks (pt, ccf,
   old, pt2 / pt2, old, ccf, pt), and per round the paired ratios new / old of our code per message and of the
   node's CPU per message. With ``--split`` also where ccf_node's own time goes, step by step (wall time per IMU
   message of each step of ``_mag``/``_imu`` and of the once-a-second timer; its timers add to that run's share).
   With ``--null`` also our code's share by difference, without a clock read in the node: ccf_node untimed and
   ccf_node without our per-message code in every round, share 1 - without / untimed.

Usage: python benchmarks/node_bench.py [--chunks 20] [--throughput-rounds 3] [--broad] [--node-cmd CMD]
       [--cpu [--rates 200,400,1000] [--chunk-s 2] [--against PYTHON] [--split] [--null]]
(sets ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST; uses ROS_DOMAIN_ID if set, else a free domain of 215-232, locked for the run)
"""

from __future__ import annotations

import argparse
import contextlib
import os
import random
import signal
import struct
import subprocess
import sys
import time
from pathlib import Path

# A domain of this run's own (locked: no test suite or other tool takes it meanwhile); child processes (spawned,
# re-importing this file) inherit it through the environment.
from ccf_ros.domains import own_domain

os.environ['ROS_DOMAIN_ID'] = str(own_domain())

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from sensor_msgs.msg import Imu, MagneticField

from ccf_ros.node import input_qos
from ccf_ros.offline.live import node_command
from ccf_ros.settings import all_defaults

HERE = Path(__file__).resolve().parent
BROAD = HERE.parents[1] / 'shared' / 'data' / 'broad' / '07_undisturbed_fast_rotation_B'
#: The nodes' input QoS (best effort, depth 50): the feeder publishes with it too, so every queue has one depth.
DEFAULTS = all_defaults()
QOS_IN = (str(DEFAULTS['qos_reliability']), int(DEFAULTS['qos_depth']))
_STAMP = struct.Struct('<iI')  # header stamp right after the 4-byte CDR encapsulation header
NAMESPACES = {'pass-through': 'pt', 'ccf_node': 'ccf', 'ccf_node old': 'ccf_old', 'ccf plain': 'ccf_plain',
              'ccf null': 'ccf_null', 'pass-through 2': 'pt2'}


def recorder(conn, namespaces: list[str]) -> None:
    """Child process: record (stamp_ns -> receive time) of <ns>/imu/data per namespace; 'take' answers with the
    records since the last 'take' and ccf_node's latest diagnostics values, 'stop' ends."""
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node(f'bench_rec_{os.getpid()}', context=ctx)
    recv: dict[str, dict[int, float]] = {ns: {} for ns in namespaces}
    diag: dict[str, str] = {}
    unpack = _STAMP.unpack_from
    qos = QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE)

    def recording(into: dict[int, float]):
        def on_out(data: bytes) -> None:
            sec, nsec = unpack(data, 4)
            into[sec * 1_000_000_000 + nsec] = time.perf_counter()
        return on_out

    def on_diag(msg: DiagnosticArray) -> None:
        for st in msg.status:
            if st.name.startswith('ccf_node'):
                diag.clear()
                diag.update({kv.key: kv.value for kv in st.values})

    for ns in namespaces:
        # Serialized, no deserialization: the probe does little, and the same for both nodes.
        node.create_subscription(Imu, f'/{ns}/imu/data', recording(recv[ns]), qos, raw=True)
    node.create_subscription(DiagnosticArray, '/diagnostics', on_diag, 10)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    conn.send('ready')
    while True:
        ex.spin_once(timeout_sec=0.01)
        if conn.poll():
            cmd = conn.recv()
            if cmd == 'take':
                conn.send(({ns: dict(r) for ns, r in recv.items()}, dict(diag)))
                for r in recv.values():
                    r.clear()
            elif cmd == 'stop':
                break
    ex.shutdown()
    node.destroy_node()
    rclpy.try_shutdown(context=ctx)


def cpu_s(pid: int) -> float:
    """CPU time (s) of a process so far, its live threads summed: the scheduler's nanosecond count of time on a CPU
    (``/proc/PID/task/TID/schedstat``, first field), not /proc/PID/stat's 10 ms ticks, which at ~100 us per message
    do not resolve a 2 s chunk to 5 %. (A thread that ends between two readings takes its time along: the nodes'
    threads live as long as the process.)"""
    total = 0
    for task in os.scandir(f'/proc/{pid}/task'):
        with contextlib.suppress(FileNotFoundError, ProcessLookupError):  # (the thread ended since the listing)
            total += int(Path(task.path, 'schedstat').read_bytes().split(None, 1)[0])
    return total * 1e-9


class Rig:
    """Both nodes (subprocesses), the feeder (this process) and the recorder (a child process)."""

    def __init__(self, cmds: dict[str, list[str]], envs: dict[str, dict[str, str]] | None = None) -> None:
        """``envs``: more environment variables for some nodes (by label)."""
        import multiprocessing as mp

        envs = envs or {}
        self.procs = {label: subprocess.Popen(cmd + ['-r', f'__ns:=/{NAMESPACES[label]}'],
                                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                              env={**os.environ, **envs.get(label, {})})
                      for label, cmd in cmds.items()}
        spawn = mp.get_context('spawn')
        self.conn, child = spawn.Pipe()
        self.rec = spawn.Process(target=recorder, args=(child, [NAMESPACES[label] for label in cmds]), daemon=True)
        self.rec.start()
        assert self.conn.recv() == 'ready'
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx)
        self.node = rclpy.create_node(f'bench_{random.randint(0, 1 << 30)}', context=self.ctx)
        qos = input_qos(*QOS_IN)
        self.pubs = {label: (self.node.create_publisher(Imu, f'/{NAMESPACES[label]}/imu/data_raw', qos),
                             self.node.create_publisher(MagneticField, f'/{NAMESPACES[label]}/imu/mag', qos))
                     for label in cmds}
        deadline = time.time() + 30
        while time.time() < deadline and not all(
                pi.get_subscription_count() and pm.get_subscription_count()
                and self.node.count_subscribers(f'/{NAMESPACES[label]}/imu/data')
                for label, (pi, pm) in self.pubs.items()):
            time.sleep(0.05)
        time.sleep(1.0)
        imu, mag = Imu(), MagneticField()
        imu.header.frame_id = mag.header.frame_id = 'imu_link'
        imu.linear_acceleration.z = 9.81
        imu.angular_velocity.x = 0.01
        mag.magnetic_field.y, mag.magnetic_field.z = 2e-5, -4e-5
        self._imu = bytearray(serialize_message(imu))
        self._mag = bytearray(serialize_message(mag))
        self.offset_ns = 1_700_000_000 * 10**9
        self.take()

    def take(self) -> tuple[dict[str, dict[int, float]], dict[str, str]]:
        """Records since the last take (per namespace) and ccf_node's latest diagnostics values."""
        self.conn.send('take')
        return self.conn.recv()

    def send(self, label: str, rate_hz: float, duration_s: float, mag_every: int = 1,
             settle_s: float = 1.0) -> tuple[dict[int, float], float]:
        """Publish IMU samples to ``label``'s node at ``rate_hz``, a magnetometer sample with the same stamp before
        every ``mag_every``-th (1: lock-step); wait ``settle_s``. Returns stamp -> send time and the node's CPU time
        (s) over the sending and the wait."""
        sent: dict[int, float] = {}
        n = int(rate_hz * duration_s)
        period = 1.0 / rate_hz
        imu, mag = self._imu, self._mag
        pack = _STAMP.pack_into
        pub_imu, pub_mag = (p.publish for p in self.pubs[label])
        cpu0 = cpu_s(self.procs[label].pid)
        t0 = time.perf_counter()
        for k in range(n):
            due = t0 + k * period
            ahead = due - time.perf_counter()
            if ahead > 0:
                time.sleep(ahead)
            stamp = self.offset_ns + int(k * period * 1e9)
            sec, nsec = divmod(stamp, 1_000_000_000)
            if k % mag_every == 0:
                pack(mag, 4, sec, nsec)
                pub_mag(bytes(mag))
            pack(imu, 4, sec, nsec)
            data = bytes(imu)
            sent[stamp] = time.perf_counter()
            pub_imu(data)
        self.offset_ns += int((duration_s + 10.0) * 1e9)
        time.sleep(settle_s)
        return sent, cpu_s(self.procs[label].pid) - cpu0

    def answered(self, label: str, sent: dict[int, float]) -> dict[int, float]:
        """Latency (s) of every answered message of the last send to ``label``."""
        recv = self.take()[0][NAMESPACES[label]]
        return {s: recv[s] - t for s, t in sent.items() if s in recv}

    def close(self) -> dict[str, int | None]:
        codes: dict[str, int | None] = {}
        for label, proc in self.procs.items():
            proc.send_signal(signal.SIGINT)
            try:
                codes[label] = proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                codes[label] = None
        self.conn.send('stop')
        self.rec.join(timeout=10)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)
        return codes


def order(labels: list[str], r: int) -> list[str]:
    """Alternate which node goes first, so that neither always runs on a warmer (or busier) machine."""
    return labels if r % 2 == 0 else labels[::-1]


def throughput_round(rig: Rig, labels: list[str], rates: list[float], r: int) -> dict[str, float]:
    """Per node, the highest loss-free rate of the ladder (rates tried on both nodes before the next)."""
    best = dict.fromkeys(labels, 0.0)
    alive = list(labels)
    log: dict[str, list[str]] = {label: [] for label in labels}
    for rate in rates:
        for label in order(list(alive), r):
            for _ in range(2):
                sent, _ = rig.send(label, rate, 2.0)
                got = len(rig.answered(label, sent))
                log[label].append(f'{rate:.0f}: {got}/{len(sent)}')
                if got == len(sent):
                    break
            if got == len(sent):
                best[label] = rate
            else:
                alive.remove(label)
        if not alive:
            break
    for label in labels:
        print(f'  throughput round {r + 1} {label:12s}: {"; ".join(log[label])}', flush=True)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--chunks', type=int, default=20, help='latency: 1 s chunks per node and magnetometer rate')
    ap.add_argument('--throughput-rounds', type=int, default=3)
    ap.add_argument('--broad', action='store_true', help='also play a BROAD trial through ccf_node (about 3 min)')
    ap.add_argument('--node-cmd', help='command of the node under test instead of the installed ccf_node '
                                       '(e.g. an older version, to compare)')
    ap.add_argument('--cpu', action='store_true', help='CPU per message at 200/400/1000 Hz and our code\'s share')
    ap.add_argument('--rates', default='200,400,1000', help='--cpu: input rates, Hz, comma-separated')
    ap.add_argument('--ccf-args', default='', help='--cpu: more ROS arguments for ccf_node (e.g. "-p use_mag:=false")')
    ap.add_argument('--chunk-s', type=float, default=2.0, help='--cpu: length of one chunk, s')
    ap.add_argument('--against', metavar='PYTHON',
                    help='--cpu: also run the node of the ccf_ros that PYTHON imports (e.g. an older checkout\'s .venv/bin/python) '
                         'in the same rounds, and print the paired ratios new / old')
    ap.add_argument('--null', action='store_true',
                    help='--cpu: also our code\'s share by difference, 1 - (ccf_node without our per-message code) / '
                         '(ccf_node untimed), per round: no clock read in either node')
    ap.add_argument('--split', action='store_true',
                    help='--cpu: also time each step of ccf_node\'s per-message code and its timer (adds to the share)')
    args = ap.parse_args()
    if (args.null or args.split or args.against) and not args.cpu:
        ap.error('--null, --split and --against go with --cpu')
    if args.split and args.against:
        # Only ccf_node carries the split's timers: they would count against it in every paired ratio.
        ap.error('--split and --against: run them separately (the split\'s timers would bias the paired ratios)')
    if args.cpu:
        cpu_per_message(args.chunks, tuple(float(r) for r in args.rates.split(',')), args.ccf_args.split(),
                        args.chunk_s, args.against, args.split, args.null)
    else:
        throughput_and_latency(args)


def throughput_and_latency(args: argparse.Namespace) -> None:
    """Parts 1-4 of the module docstring."""
    rates = [250, 500, 750, 1000, 1250, 1500, 1750, 2000, 2500, 3000, 3500, 4000, 5000, 6000, 8000]
    cmds = {'pass-through': [sys.executable, str(HERE / 'passthrough_node.py'), '--ros-args'],
            'ccf_node': (args.node_cmd.split() if args.node_cmd else node_command())
            + ['--ros-args', '--log-level', 'error']}
    labels = list(cmds)
    print(f'ROS_DOMAIN_ID={os.environ["ROS_DOMAIN_ID"]}, input QoS {QOS_IN[0]} depth {QOS_IN[1]} for the feeder and '
          f'both nodes; {args.throughput_rounds} throughput rounds and {args.chunks} latency chunks per node and '
          f'magnetometer rate, interleaved; load average {os.getloadavg()[0]:.1f}', flush=True)
    rig = Rig(cmds)
    best: dict[str, list[float]] = {k: [] for k in labels}
    lat: dict[tuple[str, int], list[np.ndarray]] = {(k, m): [] for k in labels for m in (1, 4)}
    cpu: dict[tuple[str, int], list[float]] = {key: [] for key in lat}
    try:
        for r in range(args.throughput_rounds):
            for label, rate in throughput_round(rig, labels, rates, r).items():
                best[label].append(rate)
        # Latency at 1 kHz in short chunks alternating between the nodes and magnetometer rates (ABBA), so that
        # the machine's load bursts, which last seconds, fall on both alike; percentiles over all chunks.
        for r in range(args.chunks):
            for label in order(labels, r):
                for mag_every in order([1, 4], r // 2):
                    sent, cpu_used = rig.send(label, 1000.0, 1.0, mag_every, settle_s=0.3)
                    got = rig.answered(label, sent)
                    lat[(label, mag_every)].append(np.array(list(got.values())) * 1e3)
                    cpu[(label, mag_every)].append(cpu_used / len(sent) * 1e6)
            if (r + 1) % 5 == 0:
                print(f'  latency chunks {r + 1}/{args.chunks} done', flush=True)
        diag = rig.take()[1]
    finally:
        codes = rig.close()
    print(f'  exit codes: {codes}; load average {os.getloadavg()[0]:.1f}')
    keys = ('magnetometer in lock-step', 'samples held for magnetometer', 'hold timeouts', 'hold max (ms)',
            'hold mean (ms)')
    print('  ccf_node diagnostics at the end: ' + ', '.join(f'{k} {diag.get(k)}' for k in keys))

    def pct(label: str, mag_every: int, q: float) -> float:
        return float(np.percentile(np.concatenate(lat[(label, mag_every)]), q))

    def chunk_p99(label: str, mag_every: int) -> float:
        return float(np.median([np.percentile(x, 99) for x in lat[(label, mag_every)] if len(x)]))

    def answered(label: str, mag_every: int) -> str:
        n = sum(len(x) for x in lat[(label, mag_every)])
        return f'{n}/{1000 * len(lat[(label, mag_every)])}'

    print()
    for label in labels:
        print(f'{label:12s}: highest rate without loss {np.median(best[label]):5.0f} Hz (rounds: '
              f'{", ".join(f"{b:.0f}" for b in best[label])})')
        for m in (1, 4):
            print(f'    at 1 kHz, magnetometer 1/{m}: p50 {pct(label, m, 50):.3f} ms, p99 {chunk_p99(label, m):.3f} ms '
                  f'(median of the chunks\' p99; over all chunks {pct(label, m, 99):.3f} ms), CPU '
                  f'{np.median(cpu[(label, m)]):.0f} us/message, {answered(label, m)} answered')
    print('(p99 is the median of the 1 s chunks\' p99: a load burst of another process spoils a few chunks, not the '
          'figure; p99 over all chunks shows those bursts)')
    ratio = np.median(best['ccf_node']) / np.median(best['pass-through'])
    print(f'throughput ratio ccf_node / pass-through = {ratio:.2f}   (target >= 1.0)')
    ratio = chunk_p99('ccf_node', 1) / chunk_p99('pass-through', 1)
    print(f'latency p99 ratio ccf_node / pass-through at 1 kHz = {ratio:.2f}   (target <= 1.2; over all chunks '
          f'{pct("ccf_node", 1, 99) / pct("pass-through", 1, 99):.2f})')
    ratio = np.median(cpu[('ccf_node', 1)]) / np.median(cpu[('pass-through', 1)])
    print(f'CPU time per message ratio ccf_node / pass-through at 1 kHz = {ratio:.2f}')
    for name, full, quarter in (('p50', pct('ccf_node', 1, 50), pct('ccf_node', 4, 50)),
                                ('p99', chunk_p99('ccf_node', 1), chunk_p99('ccf_node', 4))):
        verdict = 'ok' if quarter <= 1.5 * full + 0.5 else 'MISSED'
        print(f'ccf_node magnetometer at 1/4 rate vs full rate, {name}: {quarter:.3f} vs {full:.3f} ms, ratio '
              f'{quarter / full:.2f}   (target <= 1.5 x full + 0.5 ms = {1.5 * full + 0.5:.3f} ms: {verdict})')
    if args.broad:
        if BROAD.exists():
            broad_through_node()
        else:
            print(f'{BROAD} not found: BROAD run skipped')


def cpu_per_message(chunks: int, rates: tuple[float, ...] = (200.0, 400.0, 1000.0),
                    ccf_args: list[str] | None = None, chunk_s: float = 2.0, against: str | None = None,
                    split: bool = False, null: bool = False) -> None:
    """CPU time per answered IMU message (with its magnetometer message) of ccf_node and of two identical
    pass-through nodes at each rate, and the share of ccf_node's own per-message code (a fresh set of nodes per rate).

    Chunks of ``chunk_s`` per node, in rounds ordered pass-through, ccf_node, pass-through 2 and then reversed: each
    ccf_node chunk lies between the two pass-through chunks of its round, so a load that drifts over a round falls on
    both sides alike. Per round: ccf_node / mean of the two pass-throughs (the ratio), and pass-through 2 /
    pass-through (A/A: what the measurement itself makes of two identical nodes). Printed: the median of the rounds'
    ratios, their interquartile range and min-max.

    ``against``: a Python whose ccf_ros runs as ``ccf_node old`` in the same rounds (after ccf_node, before
    pass-through 2; reversed in every other round); per round the paired ratios ccf_node / ccf_node old of our code
    per message and of the node's CPU per message. ``split``: ccf_node's steps timed (``node_share.py``'s
    CCF_SPLIT_OUT), printed per rate. ``null``: two more nodes in every round, ccf_node untimed (``plain``) and
    ccf_node without our per-message code (``null``: messages taken, IMU bytes published back), and per round our
    code's share by difference, 1 - null / plain: nearly the same quantity (it also counts what our code adds to the
    once-a-second diagnostics) from the processes' CPU time alone, without the
    timed node's clock reads (a CPU-time read is a system call, ~1 us on a VM, and about half of each counts as
    ours)."""
    import tempfile

    cmds = _cpu_commands(ccf_args, against, null)
    nodes = [label for label in cmds if label.startswith('ccf_node')]
    labels = list(cmds)
    short = ', '.join(NAMESPACES[label] for label in labels)
    print(f'ROS_DOMAIN_ID={os.environ["ROS_DOMAIN_ID"]}, input QoS {QOS_IN[0]} depth {QOS_IN[1]}; {chunks} rounds of '
          f'{chunk_s:g} s chunks per node and rate, interleaved ({short} / the reverse); CPU from '
          f'/proc/PID/task/*/schedstat; load average {os.getloadavg()[0]:.1f}', flush=True)
    rows = []
    by_diff: dict[float, str] = {}  # --null: per rate, the share of the sums and its interval, as printed
    for rate in rates:
        share_files = {label: Path(tempfile.mkstemp(prefix='ccf_share_')[1]) for label in nodes}
        # (CCF_SHARE_MODE set for every node: one left in the caller's environment must not change what is measured)
        env = {label: {'CCF_SHARE_OUT': str(f), 'CCF_SHARE_MODE': 'timed'} for label, f in share_files.items()}
        if null:
            env['ccf plain'] = {'CCF_SHARE_MODE': 'plain'}
            env['ccf null'] = {'CCF_SHARE_MODE': 'null'}
        split_file = Path(tempfile.mkstemp(prefix='ccf_split_')[1]) if split else None
        if split_file is not None:
            env['ccf_node']['CCF_SPLIT_OUT'] = str(split_file)
        rig = Rig(cmds, env)
        cpu: dict[str, list[float]] = {k: [] for k in labels}  # us per answered message, per chunk
        lost: dict[str, int] = dict.fromkeys(labels, 0)
        answered: dict[str, list[str]] = {k: [] for k in labels}
        windows: dict[str, list[tuple[float, float]]] = {k: [] for k in labels}  # monotonic s of each chunk
        try:
            for r in range(chunks):
                for label in order(labels, r):
                    t_start = time.monotonic()
                    sent, cpu_used = rig.send(label, rate, chunk_s, 1, settle_s=0.3)
                    windows[label].append((t_start, time.monotonic()))
                    n_answered = len(rig.answered(label, sent))
                    lost[label] += len(sent) - n_answered
                    answered[label].append(f'{n_answered}/{len(sent)}')
                    # Per answered message: a node that falls behind drops messages at its queue, unprocessed.
                    cpu[label].append(cpu_used / max(n_answered, 1) * 1e6)
        finally:
            codes = rig.close()
        a1, a2 = np.array(cpu['pass-through']), np.array(cpu['pass-through 2'])
        aa = a2 / a1
        per = {k: float(np.median(v)) for k, v in cpu.items()}
        results = {}
        for label in nodes:
            c = np.array(cpu[label])
            ours_chunk, ours_all = _ours_per_chunk(share_files[label], windows[label])
            share = ours_chunk / c
            results[label] = (c / ((a1 + a2) / 2), ours_chunk, share)
            ours = float(np.median(ours_chunk))
            print(f'  {rate:6.0f} Hz {label} per round: ratio {" ".join(f"{x:.2f}" for x in results[label][0])}; '
                  f'our code share % {" ".join(f"{100 * x:.1f}" for x in share)}', flush=True)
            print(f'  {rate:6.0f} Hz {label}: median us/message {per[label]:.1f}; ratio {_spread(results[label][0])}; '
                  f'our code {ours:.1f} us/message, {_spread(100 * share)} % of the node\'s per chunk (over all '
                  f'messages taken: {ours_all:.1f} us/message = {100 * ours_all / per[label]:.0f} % of the median)',
                  flush=True)
        print(f'  {rate:6.0f} Hz: median us/message pass-through {per["pass-through"]:.1f}, pass-through 2 '
              f'{per["pass-through 2"]:.1f}; A/A per round {" ".join(f"{x:.2f}" for x in aa)}, {_spread(aa)}; '
              f'answered/sent {answered}; lost {lost}; exit codes {codes}; load average {os.getloadavg()[0]:.1f}',
              flush=True)
        if split_file is not None:
            _print_split(rate, split_file)
        if null:
            results['ccf plain'], by_diff[rate] = _by_difference(rate, np.array(cpu['ccf plain']),
                                                                 np.array(cpu['ccf null']), (a1 + a2) / 2)
        paired = None
        if against:
            paired = (results['ccf_node'][1] / results['ccf_node old'][1],
                      np.array(cpu['ccf_node']) / np.array(cpu['ccf_node old']))
            print(f'  {rate:6.0f} Hz paired new / old per round: our code per message '
                  f'{" ".join(f"{x:.2f}" for x in paired[0])}, {_spread(paired[0])}; node CPU per message '
                  f'{" ".join(f"{x:.2f}" for x in paired[1])}, {_spread(paired[1])}', flush=True)
        rows.append((rate, per, aa, results, paired))
    print('rate Hz | node         | node us/msg | pass-through us/msg | ratio: median [IQR] (target <= 0.8) | '
          'A/A median [IQR] (1.00 +- 0.05) | our code us/msg | share per chunk: median [IQR]; by diff.: of the sums '
          '(90 %) (<= 25 %)')
    for rate, per, aa, results, _ in rows:
        for label, (ratio, ours_chunk, share) in results.items():
            if label == 'ccf plain':  # our code = untimed - null: the ratio of the sums and its interval
                name, shown = 'by diff.', by_diff[rate]
            else:
                name, shown = label, f'{_median_iqr(100 * share, "{:.1f}")} %'
            print(f'{rate:7.0f} | {name:12s} | {per[label]:11.1f} | {per["pass-through"]:19.1f} | '
                  f'{_median_iqr(ratio)} | {_median_iqr(aa)} | {np.median(ours_chunk):15.1f} | {shown}')
    if against:
        print('rate Hz | paired new / old per round: our code per message, median [IQR] | node CPU per message, '
              'median [IQR]')
        for rate, _, _, _, paired in rows:
            print(f'{rate:7.0f} | {_median_iqr(paired[0], "{:.3f}"):55s} | {_median_iqr(paired[1], "{:.3f}")}')


def _cpu_commands(ccf_args: list[str] | None, against: str | None, null: bool) -> dict[str, list[str]]:
    """The --cpu nodes' commands by label, in a round's order; prints where each ccf_node's ccf_ros comes from."""
    passthrough = [sys.executable, str(HERE / 'passthrough_node.py'), '--ros-args']
    share_args = [str(HERE / 'node_share.py'), '--ros-args', '--log-level', 'error', *(ccf_args or [])]
    cmds = {'pass-through': passthrough, 'ccf_node': [sys.executable, *share_args]}
    if against:
        cmds['ccf_node old'] = [against, *share_args]
    if null:
        cmds['ccf plain'] = cmds['ccf null'] = [sys.executable, *share_args]
    cmds['pass-through 2'] = passthrough
    for label in cmds:
        if label.startswith('ccf_node'):
            where = subprocess.run([cmds[label][0], '-c', 'import sys, ccf_ros; print(ccf_ros.__file__, "on Python", '
                                    'sys.version.split()[0])'], cwd='/', capture_output=True, text=True).stdout.strip()
            print(f'  {label}: {cmds[label][0]}, ccf_ros from {where}', flush=True)
    return cmds


def _by_difference(rate: float, plain: np.ndarray, nothing: np.ndarray,
                   pt: np.ndarray) -> tuple[tuple[np.ndarray, ...], str]:
    """``--null``: our code's share 1 - nothing / plain per round (CPU us per message of ccf_node untimed and without
    its per-message code; ``pt`` the pass-throughs' mean), printed with the ratio of the sums and its bootstrap 90 %
    interval (the difference of two noisy totals: many rounds narrow it). Returns the table row's (ratio to the
    pass-throughs, our code us/message, share) per round, and ``share of the sums (interval) %`` as text."""
    diff = 1.0 - nothing / plain
    rng = np.random.default_rng(0)
    picks = rng.integers(0, len(plain), (20000, len(plain)))
    boot = 1.0 - nothing[picks].sum(axis=1) / plain[picks].sum(axis=1)
    shown = (f'{100 * (1.0 - nothing.sum() / plain.sum()):.1f} ({100 * np.percentile(boot, 5):.1f}-'
             f'{100 * np.percentile(boot, 95):.1f}) %')
    print(f'  {rate:6.0f} Hz by difference per round: ccf_node untimed {" ".join(f"{x:.1f}" for x in plain)} '
          f'us/message, without our code {" ".join(f"{x:.1f}" for x in nothing)}; our code\'s share % '
          f'{" ".join(f"{100 * x:.1f}" for x in diff)}, {_spread(100 * diff)}; ratio of the sums (bootstrap 90 % '
          f'interval) {shown}', flush=True)
    return (plain / pt, plain - nothing, diff), shown


def _print_split(rate: float, split_file: Path) -> None:
    """node_share.py's split (``label\\tns\\tcalls`` lines, inclusive times): us per call and per IMU message."""
    rows = [line.split('\t') for line in split_file.read_text().splitlines()]
    split_file.unlink()
    n_imu = max((int(n) for label, _, n in rows if label.startswith('IMU message')), default=0) or 1
    print(f'  {rate:6.0f} Hz where ccf_node\'s time goes (wall time, inclusive; {n_imu} IMU messages; the timer runs '
          'once a second and at hold deadlines over the node\'s whole life, start-up included; held samples are answered '
          'from _mag or the timer, so the indented rows need not add up to their parent):')
    per_message = True
    for label, ns, n in rows:
        per_message = per_message and not label.startswith('timer')
        print(f'    {label:50s} {int(ns) / 1e3 / max(int(n), 1):9.2f} us per call x {int(n):6d}'
              + (f' = {int(ns) / 1e3 / n_imu:7.2f} us per IMU message' if per_message else ''), flush=True)


def _ours_per_chunk(share_file: Path, windows: list[tuple[float, float]]) -> tuple[np.ndarray, float]:
    """Our code's time per message (us) over exactly the messages of each chunk (the same messages as its CPU
    time), from node_share.py's file (which is removed), and over every IMU message the node took (the rig's
    start-up probe included: the figure before)."""
    head, *lines = share_file.read_text().splitlines()
    share_file.unlink()
    ours_ns, n_imu, _ = (int(v) for v in head.split())
    timeline = np.array([[float(v) for v in line.split()] for line in lines]).reshape(-1, 2)
    ours_chunk = []
    for a, b in windows:
        i, j = np.searchsorted(timeline[:, 0], (a, b))
        before = timeline[i - 1, 1] if i > 0 else 0.0
        ours_chunk.append((timeline[j - 1, 1] - before) / 1e3 / max(j - i, 1) if j > i else np.nan)
    return np.array(ours_chunk), ours_ns / 1e3 / max(n_imu, 1)


def _median_iqr(x: np.ndarray, fmt: str = '{:.2f}') -> str:
    """``median [25th-75th percentile]`` of per-round values."""
    return (f'{fmt.format(np.median(x))} [{fmt.format(np.percentile(x, 25))}-'
            f'{fmt.format(np.percentile(x, 75))}]')


def _spread(x: np.ndarray) -> str:
    """Median, interquartile range and min-max of per-round ratios."""
    return (f'{np.median(x):.3f} (IQR {np.percentile(x, 25):.3f}-{np.percentile(x, 75):.3f}, '
            f'min-max {x.min():.3f}-{x.max():.3f}, n={len(x)})')


def broad_through_node() -> None:
    """A BROAD trial at 286 Hz through the installed ccf_node vs the offline engine on the same samples."""
    from ccf_ros.core import make_filter
    from ccf_ros.core.quaternion import from_xyzw
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
        ref.append(from_xyzw(*o.orientation_xyzw) if o else (np.nan,) * 4)
    ref = np.array(ref)
    print(f'  (reference: {len(ref)} samples through the same engine, magnetometer paired by stamp)')
    q = align(res.t_s, res.quat, imu.t_s, ref)
    d = 2 * np.arccos(np.clip(np.abs(np.sum(q * ref, axis=1)), 0, 1))
    print(f'\nBROAD {BROAD.name} at 286 Hz through ccf_node: {len(res.t_s)}/{res.n_imu_sent} answered, '
          f'NaN {int(np.isnan(res.quat).any(axis=1).sum())}, max |node - replay| {np.nanmax(d):.2e} rad, '
          f'exit code {res.exit_code}')


if __name__ == '__main__':
    main()
