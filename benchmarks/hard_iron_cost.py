"""Cost of the online hard iron (``mag_online_calibration``) in the engine: time per sample with it on vs off.

The engine (the node's, replay's and the fleet's per-message path) is fed a recording's arrays in one loop, no callback;
on and off alternate in interleaved rounds and the ratio of the best round of each (CPU time of this process: the machine is shared, the wall time varies with the others' load) is printed (
a ratio in one run, not absolute times). Also the share of the estimator's own work: pairing (every 0.1 s) and
solving (every 50th pair (every 5th while the applied offset moves)), by counting calls.

Usage: python benchmarks/hard_iron_cost.py [BAG] [--rounds 7] [--samples 40000]
(default: a shared BROAD trial; without it, a simulated 286 Hz hand-held recording)
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from ccf_ros.core import hard_iron
from ccf_ros.engine import ImuEngine
from ccf_ros.settings import build

BAG = Path(__file__).resolve().parents[2] / 'shared' / 'data' / 'broad' / '33_disturbed_attached_magnet_2cm'


def feed(settings: dict, t: list, gyr: list, acc: list, mag: list, has_mag: list) -> float:
    """Seconds to feed the samples to a new engine (each sample's magnetometer first, then the IMU, as replay)."""
    eng = ImuEngine(*build(settings))
    on_mag, on_imu = eng.on_mag, eng.on_imu
    t0 = time.process_time()
    for k in range(len(t)):
        if has_mag[k]:
            on_mag(t[k], mag[k])
        on_imu(t[k], gyr[k], acc[k])
    return time.process_time() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('bag', nargs='?', type=Path, default=BAG)
    ap.add_argument('--rounds', type=int, default=7)
    ap.add_argument('--samples', type=int, default=40000)
    a = ap.parse_args()
    if a.bag.exists():
        from ccf_ros.offline.bagio import read_imu_arrays

        imu = read_imu_arrays(a.bag)
        ts, g, ac, m, name = imu.t_s, imu.gyr, imu.acc, imu.mag, a.bag.name
    else:
        from ccf_ros.offline.simulate import generate

        d = generate(a.samples / 286.0 + 1.0, 286.0, 0)
        ts, g, ac, m, name = d.t_s, d.gyr, d.acc, d.mag, 'simulated hand-held, 286 Hz'
    n = min(a.samples, len(ts))
    t = ts[:n].tolist()
    gyr = [tuple(v) for v in g[:n].tolist()]
    acc = [tuple(v) for v in ac[:n].tolist()]
    mag = [tuple(v) for v in m[:n].tolist()]
    has_mag = np.all(np.isfinite(m[:n]), axis=1).tolist()
    runs = {'off': {'mag_online_calibration': False}, 'on': {'mag_online_calibration': True}}
    best = dict.fromkeys(runs, np.inf)
    for _ in range(a.rounds):
        for k, s in runs.items():
            best[k] = min(best[k], feed(s, t, gyr, acc, mag, has_mag))
    # How often the estimator does more than the per-sample check.
    est = hard_iron.HardIronEstimator
    names = {'pair': 'pair', 'update': '_update', 'decide': '_decide'}
    originals = {k: getattr(est, v) for k, v in names.items() if hasattr(est, v)}
    counts = dict.fromkeys(originals, 0)

    def counting(key: str):
        f = originals[key]

        def wrapped(self, *args, **kw):
            counts[key] += 1
            return f(self, *args, **kw)
        return wrapped

    for k in originals:
        setattr(est, names[k], counting(k))
    try:
        feed(runs['on'], t, gyr, acc, mag, has_mag)
    finally:
        for k, f in originals.items():
            setattr(est, names[k], f)
    off, on = best['off'] / n * 1e6, best['on'] / n * 1e6
    print(f'{name}, {n} samples, best of {a.rounds} interleaved rounds: engine off {off:.2f} us/sample, on '
          f'{on:.2f} us/sample: {on / off:.3f}x')
    print(f'estimator calls over the {n} samples: ' + ', '.join(f'{k} {v}' for k, v in counts.items()))


if __name__ == '__main__':
    main()
