"""Engine cost per sample with the identity mount (the rotation skipped) vs a non-identity ``mount_rotation``
(+ ``mag_rotation``) and vs ``gyro_offset_rad_s`` alone, on simulated data; runs interleaved, best of each, printed
as ratios to the identity run (one machine, one run: absolute times are not comparable elsewhere).

With ``--replay BAG``: also ``ccf replay`` of that bag (the fast CDR path), identity vs ``mount_rotation`` +
``output_frame_id`` (a new frame_id: every answer is rebuilt, its covariances turned), interleaved, best of each.

Usage: python benchmarks/frames_speed.py [--repeats 7] [--replay ../shared/data/broad/02_undisturbed_slow_rotation_B]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

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
    ap.add_argument('--replay', type=Path, help='a rosbag2 to replay too')
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
    if a.replay:
        replay_speed(a.replay, max(3, a.repeats // 2))


def replay_speed(bag: Path, repeats: int) -> None:
    """``ccf replay`` wall time, identity vs mounted output, interleaved."""
    from ccf_ros.offline.replay import replay

    cases = {'replay, identity': {}, 'replay, mount_rotation + output_frame_id': {
        'mount_rotation': [0.3, -1.1, 2.5], 'output_frame_id': 'base_link'}}
    best = {name: float('inf') for name in cases}
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(repeats):
            for name, settings in cases.items():
                s = replay(bag, Path(tmp) / f'out{i}{len(settings)}', ImuEngine(*build(settings)), progress=False)
                best[name] = min(best[name], s.wall_s / s.n_in)
    ref = best['replay, identity']
    print(f'ccf replay of {bag.name}, best of {repeats} interleaved runs')
    for name, s in best.items():
        print(f'{name:48s} {s * 1e6:7.2f} us  {s / ref:5.3f}x')


if __name__ == '__main__':
    main()
