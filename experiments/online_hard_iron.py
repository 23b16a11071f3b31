"""Online hard-iron estimation (``mag_online_calibration``), figures for issue 24 item 4.

1. Simulated hand-held motion (``generate``, 120 s at 100 Hz) with a body-fixed offset (30, -12, 8) µT: the applied
   offset's error after 60 s of motion, and the heading RMSE after it, on vs off vs the clean recording; the same
   motion in a world-fixed dipole's field (no body offset): the offset it applies (it should not follow the field).
2. BROAD trials through the engine (the node's and replay's path), defaults vs ``mag_online_calibration=true``:
   heading and total RMSE per trial and the nine-trial mean; the estimator's final status. Trial 30 has a magnet
   standing in the room (must not be followed: not worse), trial 33 a magnet attached 2 cm from the sensor (a
   body-fixed offset: expected better).
3. Cost: the engine's time per sample on one trial, off and on, interleaved (one run; a ratio).

Usage: python experiments/online_hard_iron.py [--shared DIR] [--trials 30,33] [--skip-sim] [NAME=VALUE ...]
(offline, no rclpy)
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from _trials import map_trials, parser, trials_and_settings
from simulated_accuracy import mag_env_data

from ccf_ros.core.metrics import summarize
from ccf_ros.engine import ImuEngine
from ccf_ros.offline.bagio import read_bools, read_imu_arrays, read_orientations
from ccf_ros.offline.evaluate import align, engine_orientations, mask_at
from ccf_ros.offline.simulate import SimData, dipole_field, generate
from ccf_ros.settings import build

OFFSET_T = np.array([30.0, -12.0, 8.0]) * 1e-6
ON = {'mag_online_calibration': True}
OFF = {'mag_online_calibration': False}


def run_engine(settings: dict, t: np.ndarray, gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray,
               probe_s: float | None = None, watch: list[float] | None = None,
               ) -> tuple[np.ndarray, ImuEngine, object]:
    """Orientations (N, 4) [w, x, y, z] of the engine on the arrays (mag NaN rows: no message); the engine; and its
    hard-iron status at ``t[0] + probe_s`` (None if not asked). ``watch[0]`` becomes the largest applied offset's
    norm over the run (checked every 50 samples)."""
    eng = ImuEngine(*build(settings))
    t_probe = t[0] + probe_s if probe_s is not None else None
    probe: list[object] = []

    def look(k: int, t_k: float) -> None:
        if t_probe is not None and not probe and t_k >= t_probe:
            probe.append(eng.hard_iron_status())
        if watch is not None and k % 50 == 0 and eng.hard_iron is not None:
            watch[0] = max(watch[0], float(np.linalg.norm(eng.hard_iron.status().offset)))

    q = engine_orientations(eng, t, gyr, acc, mag, look)
    return q, eng, probe[0] if probe else None


def _offset_case(offset_from_s: float) -> Callable[[int], tuple[Any, Any]]:
    """Hand-held motion, 180 s at 100 Hz, the body-fixed offset OFFSET_T from ``offset_from_s`` on (and the clean
    recording)."""
    def make(seed: int) -> tuple[Any, Any]:
        d = generate(180.0, 100.0, seed)
        mag = d.mag + np.where((d.t_s - d.t_s[0] >= offset_from_s)[:, None], OFFSET_T, 0.0)
        return SimData(t_s=d.t_s, q_true=d.q_true, gyr=d.gyr, acc=d.acc, mag=mag, bias=d.bias, moving=d.moving), d
    return make


def _passing(t: np.ndarray) -> np.ndarray:
    """A path to and fro along x over ±1 m (40 s period), starting at -1 m after the 5 s rest, m."""
    x = -np.cos(2 * np.pi * np.clip(t - 5.0, 0.0, None) / 40.0)
    return np.stack((x, 0 * x, 0 * x), axis=1)


def _world_case(field_fn: Callable[[np.random.Generator], Any], path: Any = None) -> Callable[[int], tuple[Any, Any]]:
    """Hand-held motion, 180 s at 100 Hz, in a world-fixed field (no body offset; and the clean recording)."""
    def make(seed: int) -> tuple[Any, Any]:
        rng = np.random.default_rng(2000 + seed)
        p = path if path is not None else None
        return (generate(180.0, 100.0, seed, field=field_fn(rng), path_m=p),
                generate(180.0, 100.0, seed, path_m=p))
    return make


#: Simulated cases: name -> (what, maker(seed) -> (data, clean data), whether an offset should be applied).
CASES: dict[str, tuple[str, Callable[[int], tuple[Any, Any]], bool]] = {
    'offset from start': ('body-fixed (30, -12, 8) uT from the first sample (BROAD 27)', _offset_case(0.0), True),
    'offset at 60 s': ('the same offset appears at 60 s (a magnet attached mid-run)', _offset_case(60.0), True),
    'magnet 0.25 m': ('a magnet (1 A m^2) standing 0.25 m from the hand-held sensor (BROAD 30), no offset',
                      _world_case(lambda rng: dipole_field([0.25, 0.0, 0.0], [0.0, 0.0, 1.0])), False),
    'magnet passed': ('carried to and fro over 2 m past a magnet (3 A m^2) 0.15 m beside the path, no offset',
                      _world_case(lambda rng: dipole_field([0.0, 0.15, 0.0], [3.0, 0.0, 0.0]), _passing), False),
    'steel 1.2 m': ('the dipole scenario of simulated_accuracy.py (300 A m^2 1.2 m away, hand-guided), no offset',
                    lambda seed: (mag_env_data('dipole', 100.0, seed), mag_env_data('dipole', 100.0, seed,
                                                                                    clean=True)), False),
}


def simulated(seeds: list[int]) -> None:
    """Every case of CASES, off vs on: heading RMSE over the moving samples (absolute, deg) and the largest offset
    the estimator ever applied (uT), mean over the seeds; the clean recording's heading beside."""
    print('simulated cases, 100 Hz, engine with mag_online_calibration off / on; heading RMSE over the moving '
          f'samples, deg; mean over seeds {seeds}')
    print(f'{"case":18s} {"clean":>6s} {"off":>7s} {"on":>7s}  {"max applied":>11s} {"final status":14s} what')
    for name, (what, make, should) in CASES.items():
        rows, statuses = [], []
        for seed in seeds:
            d, clean = make(seed)
            q_clean, _, _ = run_engine(OFF, clean.t_s, clean.gyr, clean.acc, clean.mag)
            q_off, _, _ = run_engine(OFF, d.t_s, d.gyr, d.acc, d.mag)
            applied: list[float] = [0.0]
            q_on, eng, _ = run_engine(ON, d.t_s, d.gyr, d.acc, d.mag, watch=applied)
            h = [summarize(q, d.q_true, d.moving).heading_rmse_deg for q in (q_clean, q_off, q_on)]
            rows.append([*h, applied[0] * 1e6])
            statuses.append(eng.hard_iron_status().status)
        m = np.mean(rows, axis=0)
        mx = max(r[3] for r in rows)
        print(f'{name:18s} {m[0]:6.2f} {m[1]:7.2f} {m[2]:7.2f}  {mx:8.2f} uT {",".join(sorted(set(statuses))):14s} '
              f'{what}{"" if should else " (must never apply)"}')


def run_trial(args: tuple[Path, dict[str, str]]) -> tuple[str, tuple]:
    trial, settings = args
    imu = read_imu_arrays(trial)
    t_ref, q_ref = read_orientations(trial, '/ground_truth/pose')
    mask = mask_at(t_ref, *read_bools(trial, '/ground_truth/moving'))
    out = []
    for extra in (OFF, ON):
        q, eng, _ = run_engine({**settings, **extra}, imu.t_s, imu.gyr, imu.acc, imu.mag)
        ok = np.all(np.isfinite(q), axis=1)
        s = summarize(align(imu.t_s[ok], q[ok], t_ref, q_ref), q_ref, mask)
        out.append((s.heading_rmse_deg, s.total_rmse_deg, eng.hard_iron_status()))
    return trial.name, tuple(out)


def cost(trial: Path) -> None:
    imu = read_imu_arrays(trial)
    n = min(len(imu.t_s), 30000)
    times: dict[str, list[float]] = {'off': [], 'on': []}
    for _ in range(3):
        for name, extra in (('off', OFF), ('on', ON)):
            t0 = time.perf_counter()
            run_engine(extra, imu.t_s[:n], imu.gyr[:n], imu.acc[:n], imu.mag[:n])
            times[name].append((time.perf_counter() - t0) / n * 1e6)
    off, on = min(times['off']), min(times['on'])
    print(f'cost ({trial.name[:2]}, {n} samples, best of 3 interleaved, includes this script\'s loop): off {off:.1f} '
          f'us/sample, on {on:.1f} us/sample: {on / off:.2f}x')


def main() -> None:
    ap = parser(__doc__)
    ap.add_argument('--skip-sim', action='store_true')
    ap.add_argument('--seeds', default='0,1,2', help='seeds of the simulated cases')
    a = ap.parse_args()
    if not a.skip_sim:
        simulated([int(v) for v in a.seeds.split(',')])
    trials, settings = trials_and_settings(a)
    results = map_trials(run_trial, [(t, settings) for t in trials])
    print(f'{"trial":40s} {"heading off":>11s} {"on":>6s}  {"total off":>9s} {"on":>6s}  status at the end')
    for name, ((h0, t0, _), (h1, t1, s)) in results:
        st = f'{s.status}, offset {" ".join(f"{v * 1e6:+.1f}" for v in s.offset)} uT, sigma ' \
             f'{max(s.sigma) * 1e6:.2f} uT, residual {s.residual_rel:.1%}'
        print(f'{name:40s} {h0:11.3f} {h1:6.3f}  {t0:9.3f} {t1:6.3f}  {st}')
    m = np.mean([[r[0][0], r[1][0], r[0][1], r[1][1]] for _, r in results], axis=0)
    print(f'{"mean of " + str(len(results)):40s} {m[0]:11.3f} {m[1]:6.3f}  {m[2]:9.3f} {m[3]:6.3f}')
    if trials:
        cost(trials[0])


if __name__ == '__main__':
    main()
