"""Accuracy of the defaults on simulated recordings unlike BROAD: other rates, noisier sensors, larger linear
accelerations, faster rotation, a drifting bias, a ground vehicle. A check that the defaults were not fitted to the
nine BROAD trials.

Each scenario is ``ccf simulate``'s hand-held motion (240 s, a 5 s rest first, uniform field) with one thing changed,
or its ground vehicle (``ccf simulate --motion vehicle``: accelerations and braking that last seconds, turns, stops,
slopes); three seeds each. Prints the mean total and inclination RMSE (9-D) and the 6-D total with one heading
offset fitted, degrees, over the moving samples.

With ``--vqf`` the same data also go through VQF (``pip install vqf``; its defaults, online, 9-D and 6-D) for a
column beside. The README's previous-default column is this script run on the core of commit 931d260.

Usage: python benchmarks/simulated_accuracy.py [--seeds 0,1,2] [--vqf] [NAME=VALUE ...]
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np
from _trials import map_trials

from ccf_ros.core import run_batch
from ccf_ros.core.metrics import fitted_total_rmse_deg, summarize
from ccf_ros.offline.simulate import generate, generate_vehicle
from ccf_ros.settings import build

#: name -> (what it is, keyword arguments of ccf_ros.offline.simulate.generate)
SCENARIOS: dict[str, tuple[str, dict[str, Any]]] = {
    'hand 286 Hz': ('the simulator as it is, at BROAD\'s rate', {'rate_hz': 286.0}),
    'hand 40 Hz': ('the same at 40 Hz', {'rate_hz': 40.0}),
    'translation x2.5': ('0.25 m translations at 100 Hz (linear accelerations to ~8 m/s²)',
                         {'rate_hz': 100.0, 'translation_m': 0.25}),
    'translation x5': ('0.5 m translations at 100 Hz (to ~15 m/s²)', {'rate_hz': 100.0, 'translation_m': 0.5}),
    'phone-grade': ('100 Hz, 4x the gyro noise, 3x accelerometer and magnetometer noise, a larger bias walking 2.5x '
                    'faster', {'rate_hz': 100.0, 'gyro_noise_rad_s': 0.02, 'acc_noise_m_s2': 0.15,
                               'mag_noise_t': 1.5e-6, 'bias_init_rad_s': np.radians(0.7),
                               'bias_walk_rad_s_sqrt_s': 5e-4}),
    'fast rotation': ('100 Hz, rotations twice as large', {'rate_hz': 100.0, 'rot_scale': 2.0}),
    'thermal drift': ('100 Hz, the bias drifting by 0.3 °/s over 2 min', {'rate_hz': 100.0,
                                                                          'bias_drift_rad_s': np.radians(0.3),
                                                                          'bias_drift_period_s': 120.0}),
    'vehicle 100 Hz': ('a ground vehicle, 0.3-1.5 m/s² for 2-6 s, turns, stops, slopes', {'vehicle': True}),
    'vehicle 50 Hz, hard': ('the same at 50 Hz, 1-3 m/s²', {'vehicle': True, 'rate_hz': 50.0,
                                                            'accel_m_s2': (1.0, 3.0)}),
}


def _data(name: str, seed: int) -> Any:
    kw = dict(SCENARIOS[name][1])
    if kw.pop('vehicle', False):
        return generate_vehicle(duration_s=240.0, seed=seed, **kw)
    return generate(duration_s=240.0, seed=seed, **kw)


def run_vqf(args: tuple[str, int]) -> tuple[str, tuple[float, float, float]]:
    """VQF (defaults, online) on the same data: its 9-D frame is ENU like ours (z up, y along the horizontal field)."""
    from vqf import VQF

    name, seed = args
    d = _data(name, seed)
    v = VQF(float(np.median(np.diff(d.t_s))))
    out = v.updateBatch(np.ascontiguousarray(d.gyr), np.ascontiguousarray(d.acc), np.ascontiguousarray(d.mag * 1e6))
    s9 = summarize(out['quat9D'], d.q_true, d.moving)
    return name, (s9.total_rmse_deg, s9.inclination_rmse_deg, fitted_total_rmse_deg(out['quat6D'], d.q_true, d.moving))


def run(args: tuple[str, int, dict[str, str]]) -> tuple[str, tuple[float, float, float]]:
    name, seed, settings = args
    d = _data(name, seed)
    f9, _ = build(settings)
    q9 = run_batch(f9, d.t_s, d.gyr, d.acc, d.mag).quat
    s9 = summarize(q9, d.q_true, d.moving)
    f6, _ = build({**settings, 'use_mag': 'false'})
    q6 = run_batch(f6, d.t_s, d.gyr, d.acc, None).quat
    return name, (s9.total_rmse_deg, s9.inclination_rmse_deg, fitted_total_rmse_deg(q6, d.q_true, d.moving))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--seeds', default='0,1,2')
    ap.add_argument('--vqf', action='store_true', help='also run VQF (pip install vqf) on the same data')
    ap.add_argument('params', nargs='*', help='NAME=VALUE filter settings')
    a = ap.parse_args()
    settings = dict(p.split('=', 1) for p in a.params)
    seeds = [int(s) for s in a.seeds.split(',')]
    if a.vqf:
        try:
            import vqf  # noqa: F401
        except ImportError:
            raise SystemExit('--vqf needs the vqf package: pip install vqf') from None
    res = map_trials(run, [(name, seed, settings) for name in SCENARIOS for seed in seeds])
    res_vqf = map_trials(run_vqf, [(name, seed) for name in SCENARIOS for seed in seeds]) if a.vqf else []
    print(f'settings {settings or "defaults"}; mean over seeds {seeds}, degrees')
    head = f'{"scenario":18s} {"9-D total":>9s} {"incl.":>7s} {"6-D fit":>8s}'
    print(head + (f'   {"VQF total":>9s} {"incl.":>7s} {"6-D fit":>8s}' if a.vqf else '') + '   what')
    rows = []
    for name, (what, _) in SCENARIOS.items():
        m = np.mean([r for n, r in res if n == name], axis=0)
        row = f'{name:18s} {m[0]:9.2f} {m[1]:7.2f} {m[2]:8.2f}'
        if a.vqf:
            v = np.mean([r for n, r in res_vqf if n == name], axis=0)
            m = np.concatenate([m, v])
            row += f'   {v[0]:9.2f} {v[1]:7.2f} {v[2]:8.2f}'
        rows.append(m)
        print(f'{row}   {what}')
    m = np.mean(rows, axis=0)
    print(f'{"mean":18s} ' + ' '.join(f'{x:{w}.2f}' for x, w in zip(m, (9, 7, 8, 11, 7, 8)[:len(m)], strict=True)))


if __name__ == '__main__':
    main()
