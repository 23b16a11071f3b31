"""Where ``ccf replay``'s and the fleet task's time goes, per IMU sample (µs of CPU), stage by stage on one bag.

Each stage is timed alone on the same data (interleaved rounds, median), so the per-call costs cProfile hides or
inflates are not in the figures:

* read: the bulk MCAP reader's chunks (``fast_batches``), and a bare rosbags read of the same records;
* decode: ``decode_chunk`` (numpy: stamps and vectors of a chunk);
* filter alone: ``OrientationFilter.update`` over the same samples, the paired magnetometer precomputed (the
  floor: the core's arithmetic and its sample rules, no engine);
* engine: ``feed_chunk`` (engine glue + filter) over the decoded chunks: with answers (replay), without answers,
  and without answers with health (the health-only task's call);
* health: ``HealthAccumulator.add_block`` over the chunks' arrays;
* records + write: the output records framed and written (``replay()`` minus the stages above).

    .venv/bin/python benchmarks/replay_budget.py [BAG] [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

BROAD02 = Path('/work/shared/data/broad')


def _default_bag() -> Path:
    trials = sorted(p for p in BROAD02.iterdir() if (p / 'metadata.yaml').exists()) if BROAD02.exists() else []
    if not trials:
        raise SystemExit('no BROAD trial found: pass a bag')
    return trials[0]


def main() -> None:  # noqa: C901 (one flat list of stages, each a closure over the same data)
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('bag', nargs='?', type=Path)
    ap.add_argument('--repeats', type=int, default=3)
    args = ap.parse_args()
    bag = args.bag or _default_bag()

    from ccf_ros.cli import build_parser, engine_settings, make_engine
    from ccf_ros.fleet.health import HealthAccumulator
    from ccf_ros.fleet.keys import code_version
    from ccf_ros.fleet.task import FleetOptions, process_bag
    from ccf_ros.offline.bagio import connections_for, in_bag_order, open_bag
    from ccf_ros.offline.mcap import fast_batches
    from ccf_ros.offline.replay import IMU, MAGNETIC_FIELD, decode_chunk, feed_chunk, replay

    merged, strict = engine_settings(build_parser().parse_args(['fleet', 'run', 'x', '-o', 'y']))

    def chunks() -> list:
        with open_bag(bag) as reader:
            imu_c = connections_for(reader, '/imu/data_raw', msgtype=IMU)
            mag_c = connections_for(reader, '/imu/mag', msgtype=MAGNETIC_FIELD)
            conns = in_bag_order(reader, imu_c + mag_c)
            is_imu = np.array([c in imu_c for c in conns])
            batches = fast_batches(reader, conns)
            assert batches is not None
            return [(cols, is_imu[cols.owner]) for cols in batches]

    cached = chunks()
    decoded = [decode_chunk(cols, imu) for cols, imu in cached]
    n_imu = sum(len(d[1]) for d in decoded)
    # The filter's inputs exactly as the engine gives them (paired magnetometer included), recorded once.
    eng = make_engine(merged, strict)
    # (the default settings: the filter gets the stamps, vectors and paired magnetometer samples as they are)
    rows: list = []
    for (_cols, imu), d in zip(cached, decoded, strict=True):
        _, ii, _, t_all, v1, v2 = d
        ans = eng.on_chunk(imu.tolist(), t_all.tolist(), tuple(v1.T.tolist()), tuple(v2.T.tolist()), observe=True)
        pm = np.array(ans.paired_mag).reshape(-1, 3).tolist()
        rows += zip(t_all[ii].tolist(), v1[ii].tolist(), v2[ii].tolist(),
                    [None if m[0] != m[0] else m for m in pm], strict=True)
    health_in = []
    for d in decoded:
        _, ii, _, t_all, v1, v2 = d
        health_in.append((t_all[ii], v1[ii], v2[ii], np.full((len(ii), 3), 0.3e-4), np.zeros(len(ii), bool)))

    def bare() -> None:
        with open_bag(bag) as reader:
            conns = [c for c in reader.connections if c.topic in ('/imu/data_raw', '/imu/mag')]
            for _ in reader.messages(connections=conns):
                pass

    def read() -> None:
        chunks()

    def decode() -> None:
        for cols, imu in cached:
            decode_chunk(cols, imu)

    def filter_alone() -> None:
        f = make_engine(merged, strict).filter
        update = f._update_floats  # (what the engine calls per sample: update() only unpacks into it)
        for t, (gx, gy, gz), (ax, ay, az), m in rows:
            update(t, gx, gy, gz, ax, ay, az, m)

    def engine_alone() -> None:
        e = make_engine(merged, strict)
        for (_cols, imu), d in zip(cached, decoded, strict=True):
            feed_chunk(e, imu, d[1], d[3], d[4], d[5])

    def engine_no_answers() -> None:
        e = make_engine(merged, strict)
        for (_cols, imu), d in zip(cached, decoded, strict=True):
            feed_chunk(e, imu, d[1], d[3], d[4], d[5], answers=False)

    def engine_health() -> None:
        e = make_engine(merged, strict)
        h = HealthAccumulator()
        for (_cols, imu), d in zip(cached, decoded, strict=True):
            feed_chunk(e, imu, d[1], d[3], d[4], d[5], h, answers=False)

    def health() -> None:
        h = HealthAccumulator()
        for block in health_in:
            h.add_block(*block)
        h.result()

    work = Path(tempfile.mkdtemp(prefix='ccf_budget_'))

    def replay_all() -> None:
        replay(bag, work / 'r', make_engine(merged, strict), overwrite=True, progress=False)

    def task_health() -> None:
        opts = FleetOptions(out=str(work / 't'), settings=merged, strict=strict, version=code_version(),
                            reference='')
        assert process_bag(str(bag), 'h', opts)['status'] == 'ok'

    stages: dict[str, Callable[[], None]] = {
        'bare rosbags read (IMU+mag records)': bare, 'bulk reader (fast_batches)': read, 'decode_chunk': decode,
        'filter alone (_update_floats)': filter_alone, 'feed_chunk, no health (glue+filter)': engine_alone,
        'feed_chunk, no answers, no health': engine_no_answers, 'feed_chunk + health, no answers': engine_health, 'health add_block alone': health,
        'replay() whole': replay_all, 'fleet task, health only': task_health}
    cpu: dict[str, list[float]] = {k: [] for k in stages}
    for _ in range(args.repeats):
        for name, fn in stages.items():
            c0 = time.process_time()
            fn()
            cpu[name].append(time.process_time() - c0)
    med = {k: statistics.median(v) / n_imu * 1e6 for k, v in cpu.items()}
    print(f'{bag.name}: {n_imu} IMU samples; µs CPU per IMU sample (median of {args.repeats}); '
          f'load {os.getloadavg()[0]:.1f}')
    for k, v in med.items():
        print(f'  {k:42s} {v:7.2f} µs   {1e6 / v:10,.0f} samples/CPU s')
    glue = med['feed_chunk, no health (glue+filter)'] - med['filter alone (_update_floats)']
    write = (med['replay() whole'] - med['bulk reader (fast_batches)'] - med['decode_chunk']
             - med['feed_chunk, no health (glue+filter)'])
    print(f'  => engine glue (feed_chunk - filter) {glue:.2f} µs; records+write (replay - read - decode - feed) '
          f'{write:.2f} µs')
    print(f'  => replay at 44,000/CPU s needs <= {1e6 / 44000:.2f} µs per sample in all')


if __name__ == '__main__':
    main()
