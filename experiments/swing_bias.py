"""Where the planar swing's 6-D heading error comes from: the gyro bias's vertical component, learnt or not.

The pendulum of ``experiments/simulated_accuracy.py --mag`` ('planar swing', 200 s, a 5 s rest first) at 40, 100
and 286 Hz, per seed: the 6-D heading RMSE (one offset fitted) of the defaults, of the defaults without learning the
bias while moving (``motion_bias=false``) and of VQF 6D (with ``--vqf``), and the defaults' bias error (estimate
minus the simulated bias, rotated into the world by the true attitude), mean |vertical| and |horizontal| over the
moving samples, °/s, beside the same without motion learning. A heading drifts at the vertical component's rate.

Usage: python experiments/swing_bias.py [--seeds 0,1,2] [--vqf] [NAME=VALUE ...]
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np
from _trials import map_trials
from simulated_accuracy import MAG_RATES, _heading_rmse

from ccf_ros.core import run_batch
from ccf_ros.core.quaternion import quat_rotate
from ccf_ros.offline.simulate import generate_swing
from ccf_ros.settings import build


def _bias_error(bias: np.ndarray, d: Any) -> tuple[float, float]:
    """Mean |vertical| and |horizontal| bias error over the moving samples, °/s (world frame, true attitude)."""
    e = quat_rotate(d.q_true, bias - d.bias)[d.moving]
    return float(np.degrees(np.abs(e[:, 2]).mean())), float(np.degrees(np.hypot(e[:, 0], e[:, 1]).mean()))


def run(args: tuple[float, int, dict[str, str], bool]) -> tuple[float, int, list[float]]:
    """(rate, seed, [heading, heading without motion learning, VQF heading, vertical, horizontal, vertical and
    horizontal without motion learning]) of one run."""
    rate, seed, settings, vqf = args
    d = generate_swing(200.0, rate, seed)
    out = [float('nan')] * 7
    errs = []
    for i, extra in enumerate(({}, {'motion_bias': 'false'})):
        f, _ = build({**settings, **extra, 'use_mag': 'false'})
        r = run_batch(f, d.t_s, d.gyr, d.acc, None)
        out[i] = _heading_rmse(r.quat, d.q_true, d.moving, fitted=True)
        errs += _bias_error(r.bias, d)
    out[3:7] = errs
    if vqf:
        from vqf import VQF

        q = VQF(1.0 / rate).updateBatch(np.ascontiguousarray(d.gyr), np.ascontiguousarray(d.acc))['quat6D']
        out[2] = _heading_rmse(q, d.q_true, d.moving, fitted=True)
    return rate, seed, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--seeds', default='0,1,2')
    ap.add_argument('--vqf', action='store_true', help='also VQF 6D (pip install vqf)')
    ap.add_argument('params', nargs='*', help='NAME=VALUE filter settings')
    a = ap.parse_args()
    settings = dict(p.split('=', 1) for p in a.params)
    seeds = [int(s) for s in a.seeds.split(',')]
    res = map_trials(run, [(r, s, settings, a.vqf) for r in MAG_RATES for s in seeds])
    print(f'planar swing, 6-D; settings {settings or "defaults"}; heading RMSE (offset fitted), deg; bias error, °/s')
    print(f'{"rate":>5s} {"seed":>4s} {"heading":>8s} {"no m.b.":>8s} {"VQF 6D":>8s}   {"vert":>6s} {"horiz":>6s}'
          f'   {"no m.b.: vert":>13s} {"horiz":>6s}')
    for rate in MAG_RATES:
        rows = [o for r, _, o in res if r == rate]
        for (_, s, o) in [x for x in res if x[0] == rate]:
            print(f'{rate:5.0f} {s:4d} {o[0]:8.2f} {o[1]:8.2f} {o[2]:8.2f}   {o[3]:6.3f} {o[4]:6.3f}   {o[5]:13.3f} {o[6]:6.3f}')
        m = np.mean(rows, axis=0)
        print(f'{rate:5.0f} {"mean":>4s} {m[0]:8.2f} {m[1]:8.2f} {m[2]:8.2f}   {m[3]:6.3f} {m[4]:6.3f}   {m[5]:13.3f} '
              f'{m[6]:6.3f}')


if __name__ == '__main__':
    main()
