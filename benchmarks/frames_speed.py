"""Engine cost per sample with the identity mount (the rotation skipped) vs a non-identity ``mount_rotation``
(+ ``mag_rotation``) and vs ``gyro_offset_rad_s`` alone, on simulated data; runs interleaved, best of each, printed
as ratios to the identity run (one machine, one run: absolute times are not comparable elsewhere).

Usage: python benchmarks/frames_speed.py [--repeats 7]
"""

from __future__ import annotations

import argparse
import time

from ccf_ros.engine import ImuEngine
from ccf_ros.offline.simulate import generate
from ccf_ros.settings import build

CASES = {
    'identity (default)': {},
    'mount_rotation [0.3, -1.1, 2.5]': {'mount_rotation': [0.3, -1.1, 2.5]},
    'mount_rotation + mag_rotation': {'mount_rotation': [0.3, -1.1, 2.5], 'mag_rotation': [0.0, 0.0, 1.0]},
    'gyro_offset_rad_s only': {'gyro_offset_rad_s': [0.01, 0.02, 0.03]},
    'mount_rotation + output_frame_id (engine only)': {'mount_rotation': [0.0, 0.0, 1.5707963267948966],
                                                       'output_frame_id': 'base_link'},
}


def once(settings: dict, data: tuple) -> float:
    """Seconds per sample of one engine over the data."""
    eng = ImuEngine(*build(settings))
    on_mag, on_imu = eng.on_mag, eng.on_imu
    t0 = time.perf_counter()
    for t, g, a, m in data:
        on_mag(t, m)
        on_imu(t, g, a)
    return (time.perf_counter() - t0) / len(data)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--repeats', type=int, default=7)
    a = ap.parse_args()
    d = generate(60.0, 286.0, seed=1)
    data = list(zip(d.t_s.tolist(), map(tuple, d.gyr.tolist()), map(tuple, d.acc.tolist()),
                    map(tuple, d.mag.tolist()), strict=True))
    best = {name: float('inf') for name in CASES}
    for _ in range(a.repeats):
        for name, settings in CASES.items():  # interleaved: load changes hit every case alike
            best[name] = min(best[name], once(settings, data))
    ref = best['identity (default)']
    print(f'engine per sample, best of {a.repeats} interleaved runs over {len(data)} samples')
    for name, s in best.items():
        print(f'{name:48s} {s * 1e6:7.2f} us  {s / ref:5.3f}x')


if __name__ == '__main__':
    main()
