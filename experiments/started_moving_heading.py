"""9-D heading after a start in strong motion, in a homogeneous field, against the gyro bias along world up.

The case of ``test_started_while_moving_the_heading_converges`` (the simulator's hand motion with 0.3 m translations,
200 Hz, 150 s; the filter started 30 s in, so no rest teaches it the bias) over more seeds. Heading is absolute for
9-D (RMSE from 30 s after the start), one offset fitted for 6-D; beside it the true bias along world up at the start.

What it shows (doc/history/2026-12-07-session23.md): a bias along up of more than ~0.4 °/s leaves 9-D heading off by
up to b x tau_mag_s for minutes in a clean field. The blend lags the field by b x tau_mag_s and the NCF by
b x tau_ncf_s, so the two stages' headings differ by b (tau_mag_s - tau_ncf_s) (~17° for 1.4 °/s), beyond the ±5° in
which the bias's heading rows learn; only the tilt rows learn the up component, as the body's turns show it to them.

Usage: python experiments/started_moving_heading.py [--seeds 0,...,23] [NAME=VALUE ...]
"""

from __future__ import annotations

import argparse

import numpy as np
from _trials import map_trials
from simulated_accuracy import _heading_rmse

from ccf_ros.core import run_batch
from ccf_ros.core.quaternion import quat_conj, quat_rotate
from ccf_ros.offline.simulate import generate
from ccf_ros.settings import build

RATE_HZ = 200.0
START_S = 30.0
#: Heading is scored from this long after the start, s.
SCORED_AFTER_S = 30.0


def run(args: tuple[int, dict[str, str]]) -> tuple[int, tuple[float, float, float]]:
    """9-D heading RMSE, 6-D heading RMSE (offset fitted), degrees; the true bias along world up at the start, °/s."""
    seed, settings = args
    d = generate(150.0, RATE_HZ, seed=seed, translation_m=0.3)
    k0 = int(START_S * RATE_HZ)
    late = d.t_s[k0:] - d.t_s[k0] > SCORED_AFTER_S
    f9, _ = build(settings)
    f6, _ = build({**settings, 'use_mag': 'false'})
    q9 = run_batch(f9, d.t_s[k0:], d.gyr[k0:], d.acc[k0:], d.mag[k0:]).quat
    q6 = run_batch(f6, d.t_s[k0:], d.gyr[k0:], d.acc[k0:], None).quat
    up_body = quat_rotate(quat_conj(d.q_true[k0]), np.array([0.0, 0.0, 1.0]))
    return seed, (_heading_rmse(q9, d.q_true[k0:], late, fitted=False), _heading_rmse(q6, d.q_true[k0:], late, fitted=True),
                  float(np.degrees(d.bias[k0] @ up_body)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--seeds', default=','.join(str(s) for s in range(24)))
    ap.add_argument('params', nargs='*', help='NAME=VALUE filter settings')
    a = ap.parse_args()
    settings = dict(p.split('=', 1) for p in a.params)
    seeds = [int(s) for s in a.seeds.split(',')]
    res = dict(map_trials(run, [(s, settings) for s in seeds]))
    print(f'settings {settings or "defaults"}; started {START_S:.0f} s into 0.3 m hand motion at {RATE_HZ:.0f} Hz; '
          f'heading RMSE from {SCORED_AFTER_S:.0f} s after the start, degrees')
    print(f'{"seed":>4s} {"head 9-D":>8s} {"6-D fit":>8s} {"bias up °/s":>11s}')
    for s in seeds:
        h9, h6, b_up = res[s]
        print(f'{s:4d} {h9:8.2f} {h6:8.2f} {b_up:11.2f}')
    m = np.array([res[s] for s in seeds])
    big = np.abs(m[:, 2]) > 0.4
    print(f'mean {m[:, 0].mean():8.2f} {m[:, 1].mean():8.2f}   (9-D worst {m[:, 0].max():.2f}; '
          f'9-D mean where |bias up| > 0.4 °/s: {m[big, 0].mean() if big.any() else float("nan"):.2f} over '
          f'{int(big.sum())} seeds, else {m[~big, 0].mean() if (~big).any() else float("nan"):.2f})')


if __name__ == '__main__':
    main()
