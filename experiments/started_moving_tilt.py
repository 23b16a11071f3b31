"""9-D against 6-D inclination on simulated hand-held motion like the arm-chain recordings of issue 23 (40 Hz, 67 s,
a dipole field or a uniform one), started after a 0.5 s or a 5 s rest: where the magnetometer's presence costs tilt.

The 9-D filter learns no gyro bias while moving until its heading blend has handed over from the start-up's running
mean (``tau_mag_s``, 15 s); 6-D learns from the tilt blends' hand-over (``tau_acc_lp_s``, 2.5 s) on while its tilt
error is one a bias could hold. Started while moving, the bias stays unlearnt for longer in 9-D and its tilt is worse;
with ``tau_mag_s`` 60 far worse (the issue's 0.74 -> 1.29).

A second table starts the filter 30 s into the simulator's hand motion at 100 Hz (translations of 0.1, 0.25 and
0.5 m, linear accelerations to ~15 m/s²), where the first accelerometer samples tilt the start by degrees: inclination
from 10 s after the start, 9-D beside 6-D (the bias must not learn the start-up's tilt error as drift).

Usage: python experiments/started_moving_tilt.py [--seeds 0,...,5] [--mid-seeds 0,...,11] [NAME=VALUE ...]
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np
from _trials import map_trials
from simulated_accuracy import _heading_rmse

from ccf_ros.core import run_batch
from ccf_ros.core.metrics import summarize
from ccf_ros.offline.simulate import dipole_field, generate, wander_path
from ccf_ros.settings import build

#: (rest before the motion, s; field)
CASES = ((0.5, 'dipole'), (0.5, 'uniform'), (5.0, 'dipole'), (5.0, 'uniform'))


def run(args: tuple[float, str, int, dict[str, str]]) -> tuple[tuple[float, str], tuple[float, ...]]:
    rest, field, seed, settings = args
    rng = np.random.default_rng(1000 + seed)
    # The dipole of simulated_accuracy.py's 'dipole' environment (a horizontal moment 1.2 m away).
    ang = rng.uniform(0.0, 2.0 * np.pi)
    center = 1.2 * np.array([np.cos(ang), np.sin(ang), rng.uniform(-0.3, 0.3)])
    moment = 300.0 * rng.choice([-1.0, 1.0]) * np.array([-np.sin(ang), np.cos(ang), 0.0])
    f: Any = dipole_field(center, moment) if field == 'dipole' else None
    d = generate(67.0, 40.0, seed, rest_s=rest, translation_m=0.1, field=f, path_m=wander_path(0.35, rng))
    f9, _ = build(settings)
    f6, _ = build({**settings, 'use_mag': 'false'})
    q9 = run_batch(f9, d.t_s, d.gyr, d.acc, d.mag).quat
    q6 = run_batch(f6, d.t_s, d.gyr, d.acc, None).quat
    mv = d.moving
    return (rest, field), (summarize(q9, d.q_true, mv).inclination_rmse_deg,
                           summarize(q6, d.q_true, mv).inclination_rmse_deg,
                           _heading_rmse(q9, d.q_true, mv, fitted=True), _heading_rmse(q6, d.q_true, mv, fitted=True))


#: Translation amplitudes (m) of the mid-motion starts.
MID_TRANSLATIONS_M = (0.1, 0.25, 0.5)


def run_mid(args: tuple[float, int, dict[str, str]]) -> tuple[float, tuple[float, float]]:
    """Started 30 s into 80 s of hand motion at 100 Hz: inclination RMSE (deg) from 10 s after the start, 9-D and
    6-D."""
    translation, seed, settings = args
    d = generate(80.0, 100.0, seed, translation_m=translation)
    k0 = 30 * 100
    late = d.moving[k0:] & (d.t_s[k0:] - d.t_s[k0] > 10.0)
    f9, _ = build(settings)
    f6, _ = build({**settings, 'use_mag': 'false'})
    q9 = run_batch(f9, d.t_s[k0:], d.gyr[k0:], d.acc[k0:], d.mag[k0:]).quat
    q6 = run_batch(f6, d.t_s[k0:], d.gyr[k0:], d.acc[k0:], None).quat
    return translation, (summarize(q9, d.q_true[k0:], late).inclination_rmse_deg,
                         summarize(q6, d.q_true[k0:], late).inclination_rmse_deg)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--seeds', default='0,1,2,3,4,5')
    ap.add_argument('--mid-seeds', default=','.join(str(s) for s in range(12)))
    ap.add_argument('params', nargs='*', help='NAME=VALUE filter settings')
    a = ap.parse_args()
    settings = dict(p.split('=', 1) for p in a.params)
    seeds = [int(s) for s in a.seeds.split(',')]
    res = map_trials(run, [(*c, s, settings) for c in CASES for s in seeds])
    print(f'settings {settings or "defaults"}; 67 s at 40 Hz, mean over seeds {seeds}, degrees')
    print(f'{"rest, field":16s} {"incl 9-D":>8s} {"6-D":>6s} {"head 9-D":>8s} {"6-D":>6s}  (heading: one offset fitted)')
    for c in CASES:
        m = np.mean([x for k, x in res if k == c], axis=0)
        print(f'{f"{c[0]:.1f} s, {c[1]}":16s} {m[0]:8.3f} {m[1]:6.3f} {m[2]:8.3f} {m[3]:6.3f}')
    mid_seeds = [int(s) for s in a.mid_seeds.split(',')]
    mid = map_trials(run_mid, [(tr, s, settings) for tr in MID_TRANSLATIONS_M for s in mid_seeds])
    print(f'\nstarted 30 s into the motion, 100 Hz, mean over seeds {mid_seeds}: inclination from 10 s after the start')
    print(f'{"translation":16s} {"incl 9-D":>8s} {"6-D":>6s} {"worst 6-D":>9s}')
    for tr in MID_TRANSLATIONS_M:
        m = np.array([x for k, x in mid if k == tr])
        print(f'{f"{tr:.2f} m":16s} {m[:, 0].mean():8.3f} {m[:, 1].mean():6.3f} {m[:, 1].max():9.3f}')


if __name__ == '__main__':
    main()
