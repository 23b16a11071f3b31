"""Accuracy of the defaults on simulated recordings unlike BROAD: other rates, noisier sensors, larger linear
accelerations, faster rotation, a drifting bias, a ground vehicle. A check that the defaults were not fitted to the
nine BROAD trials.

Each scenario is ``ccf simulate``'s hand-held motion (240 s, a 5 s rest first, uniform field) with one thing changed,
or its ground vehicle (``ccf simulate --motion vehicle``: accelerations and braking that last seconds, turns, stops,
slopes); three seeds each. Prints the mean total and inclination RMSE (9-D) and the 6-D total with one heading
offset fitted, degrees, over the moving samples.

With ``--vqf`` the same data also go through VQF (``pip install vqf``; its defaults, online, 9-D and 6-D) for a
column beside. The README's previous-default column is this script run on the core of commit 931d260.

A second table, magnetic environments, at 40, 100 and 286 Hz (``--mag`` only it, ``--no-mag-envs`` without it):

* *dipole*: hand-guided motion (90 s, wandering slowly over ±0.35 m) through a field that varies with position (a
  horizontal dipole of 300 A m² 1.2 m away: the field's direction spreads by ~16° RMS over the workspace, its norm
  by ~25 %, its dip by ~10°, as measured on a real arm-chain set); heading RMSE with one offset fitted per run, 9-D
  beside 6-D (the magnetometer must not make it worse);
* *new building*: a uniform field whose norm drops by 20 % and dip rises by 8° at 60 s (a robot drives into a
  steel-framed building; north unchanged): heading RMSE from 60 s after the change on, minus a clean run's;
* *start at magnet*: the first 5 s at rest 0.25 m from a magnet (a dipole of 3 A m²: the field 25° off), then
  carried 2 m away over 4 s: heading RMSE from 60 s after leaving, minus a clean run's;
* *planar swing*: a pendulum (0.5 m, pushed to 10-45°, 200 s) in 6-D: heading RMSE with one offset fitted.

Usage: python experiments/simulated_accuracy.py [--seeds 0,1,2] [--vqf] [--mag | --no-mag-envs] [NAME=VALUE ...]
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np
from _trials import map_trials, run_9d

from ccf_ros.core import run_batch
from ccf_ros.core.metrics import error_angles, fit_heading_offset, fitted_total_rmse_deg, summarize
from ccf_ros.offline.simulate import (
    dipole_field,
    field_change,
    generate,
    generate_near_dipole,
    generate_swing,
    generate_vehicle,
)
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


#: Magnetic environments: name -> (what, rates). See the module docstring.
MAG_ENVS: dict[str, str] = {
    'dipole': 'hand-guided through a field that varies with position; heading, offset fitted: 9-D vs 6-D',
    'new building': 'the uniform field changes (norm -20 %, dip +8°) at 60 s; heading from 60 s after, minus clean',
    'start at magnet': 'starts 0.25 m from a magnet, carried away at 5 s; heading from 60 s after, minus clean',
    'planar swing': 'a pendulum, 6-D: heading, offset fitted',
}
MAG_RATES = (40.0, 100.0, 286.0)
#: When the field changes in 'new building' and when the motion leaves the magnet in 'start at magnet', s.
T_CHANGE_S = 60.0
T_LEAVE_S = 5.0


def _away(t: np.ndarray) -> np.ndarray:
    """A path from the start 2 m along x, smoothly over the 4 s after T_LEAVE_S, m."""
    r = np.clip((t - T_LEAVE_S) / 4.0, 0.0, 1.0)
    x = 2.0 * r * r * (3 - 2 * r)
    return np.stack((x, 0 * x, 0 * x), axis=1)


def mag_env_data(name: str, rate: float, seed: int, *, clean: bool = False) -> Any:
    """The recording of magnetic environment ``name`` (``clean``: the same motion and noise in the uniform field)."""
    if name == 'dipole':
        # Hand-guided: the hand's wobble about a point that wanders slowly (0.02-0.08 Hz) over ±0.35 m, so the
        # sensor spends seconds in each part of a field that a horizontal dipole 1.2 m away turns.
        return generate_near_dipole(rate, seed, uniform=clean)
    if name == 'new building':
        f = None if clean else field_change(T_CHANGE_S, 0.8, np.radians(8.0))
        return generate(T_CHANGE_S + 120.0, rate, seed, field=f)
    if name == 'start at magnet':
        # A magnet 0.25 m to the side of the start, its moment turning the field there by ~25°.
        f = None if clean else dipole_field([0.0, -0.25, 0.0], [3.0, 0.0, 0.0])
        return generate(T_LEAVE_S + 4.0 + 120.0, rate, seed, field=f, path_m=_away, rest_s=T_LEAVE_S)
    if name == 'planar swing':
        return generate_swing(200.0, rate, seed)
    raise KeyError(name)


def _heading_rmse(q: np.ndarray, q_true: np.ndarray, sel: np.ndarray, *, fitted: bool) -> float:
    """Heading RMSE, degrees, over ``sel`` (one heading offset fitted first with ``fitted``)."""
    ref = q_true[sel]
    if fitted:
        ref = fit_heading_offset(q[sel], ref)
    return float(np.degrees(np.sqrt(np.mean(error_angles(q[sel], ref)[1] ** 2))))


def _mag_env_figures(name: str, d: Any, q9: np.ndarray | None, q6: np.ndarray | None, clean_q9: np.ndarray | None,
                     clean: Any) -> tuple[float, float, float]:
    """(figure, 9-D inclination, 6-D inclination) of one run; the figure per environment as MAG_ENVS says (for the
    dipole: 9-D minus 6-D heading)."""
    mv = d.moving
    inc9 = summarize(q9, d.q_true, mv).inclination_rmse_deg if q9 is not None else float('nan')
    inc6 = summarize(q6, d.q_true, mv).inclination_rmse_deg if q6 is not None else float('nan')
    if name == 'dipole':
        return _heading_rmse(q9, d.q_true, mv, fitted=True), _heading_rmse(q6, d.q_true, mv, fitted=True), inc9
    if name == 'planar swing':
        return _heading_rmse(q6, d.q_true, mv, fitted=True), float('nan'), inc6
    t0 = (T_CHANGE_S if name == 'new building' else T_LEAVE_S + 4.0) + 60.0
    after = (d.t_s - d.t_s[0]) >= t0
    return (_heading_rmse(q9, d.q_true, after, fitted=False) - _heading_rmse(clean_q9, clean.q_true, after, fitted=False),
            _heading_rmse(clean_q9, clean.q_true, after, fitted=False), inc9)


def run_mag_env(args: tuple[str, float, int, dict[str, str]]) -> tuple[str, float, tuple[float, float, float]]:
    name, rate, seed, settings = args
    d = mag_env_data(name, rate, seed)
    f9, a9 = build(settings)
    f6, _ = build({**settings, 'use_mag': 'false'})
    q9 = run_9d(f9, a9, d.t_s, d.gyr, d.acc, d.mag)[0] if name != 'planar swing' else None
    q6 = run_batch(f6, d.t_s, d.gyr, d.acc, None).quat if name in ('dipole', 'planar swing') else None
    clean = clean_q9 = None
    if name in ('new building', 'start at magnet'):
        clean = mag_env_data(name, rate, seed, clean=True)
        f9c, a9c = build(settings)
        clean_q9 = run_9d(f9c, a9c, clean.t_s, clean.gyr, clean.acc, clean.mag)[0]
    return name, rate, _mag_env_figures(name, d, q9, q6, clean_q9, clean)


def run_mag_env_vqf(args: tuple[str, float, int]) -> tuple[str, float, tuple[float, float, float]]:
    from vqf import VQF

    name, rate, seed = args

    def vqf(d: Any) -> dict[str, np.ndarray]:
        v = VQF(1.0 / rate)
        return v.updateBatch(np.ascontiguousarray(d.gyr), np.ascontiguousarray(d.acc),
                             np.ascontiguousarray(d.mag * 1e6))

    d = mag_env_data(name, rate, seed)
    out = vqf(d)
    clean = clean_q9 = None
    if name in ('new building', 'start at magnet'):
        clean = mag_env_data(name, rate, seed, clean=True)
        clean_q9 = vqf(clean)['quat9D']
    return name, rate, _mag_env_figures(name, d, out['quat9D'], out['quat6D'], clean_q9, clean)


def _print_mag_envs(res: list[Any], res_vqf: list[Any]) -> None:
    print('\nmagnetic environments (degrees; mean over seeds):')
    for name, what in MAG_ENVS.items():
        print(f'  {name}: {what}')
    print(f'{"environment":16s} {"rate":>5s}   {"ccf":>22s}   {"VQF":>22s}')
    for name in MAG_ENVS:
        for rate in MAG_RATES:
            m = np.mean([r for n, rt, r in res if n == name and rt == rate], axis=0)
            v = np.mean([r for n, rt, r in res_vqf if n == name and rt == rate], axis=0) if res_vqf else None
            if name == 'dipole':
                cells = [f'9-D {m[0]:5.2f} 6-D {m[1]:5.2f} i {m[2]:4.2f}',
                         f'9-D {v[0]:5.2f} 6-D {v[1]:5.2f} i {v[2]:4.2f}' if v is not None else '']
            elif name == 'planar swing':
                cells = [f'6-D {m[0]:5.2f} i {m[2]:4.2f}', f'6-D {v[0]:5.2f} i {v[2]:4.2f}' if v is not None else '']
            else:
                cells = [f'{m[0]:+5.2f} (clean {m[1]:4.2f})',
                         f'{v[0]:+5.2f} (clean {v[1]:4.2f})' if v is not None else '']
            print(f'{name:16s} {rate:5.0f}   {cells[0]:>22s}   {cells[1]:>22s}')


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
    f9, a9 = build(settings)
    q9 = run_9d(f9, a9, d.t_s, d.gyr, d.acc, d.mag)[0]
    s9 = summarize(q9, d.q_true, d.moving)
    f6, _ = build({**settings, 'use_mag': 'false'})
    q6 = run_batch(f6, d.t_s, d.gyr, d.acc, None).quat
    return name, (s9.total_rmse_deg, s9.inclination_rmse_deg, fitted_total_rmse_deg(q6, d.q_true, d.moving))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--seeds', default='0,1,2')
    ap.add_argument('--vqf', action='store_true', help='also run VQF (pip install vqf) on the same data')
    which = ap.add_mutually_exclusive_group()
    which.add_argument('--mag', action='store_true', help='only the magnetic environments')
    which.add_argument('--no-mag-envs', action='store_true', help='without the magnetic environments')
    ap.add_argument('params', nargs='*', help='NAME=VALUE filter settings')
    a = ap.parse_args()
    settings = dict(p.split('=', 1) for p in a.params)
    seeds = [int(s) for s in a.seeds.split(',')]
    if a.vqf:
        try:
            import vqf  # noqa: F401
        except ImportError:
            raise SystemExit('--vqf needs the vqf package: pip install vqf') from None
    if not a.no_mag_envs:
        jobs = [(name, rate, seed) for name in MAG_ENVS for rate in MAG_RATES for seed in seeds]
        res_env = map_trials(run_mag_env, [(*j, settings) for j in jobs])
        res_env_vqf = map_trials(run_mag_env_vqf, jobs) if a.vqf else []
        _print_mag_envs(res_env, res_env_vqf)
        if a.mag:
            return
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
