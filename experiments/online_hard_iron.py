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
from pathlib import Path

import numpy as np
from _trials import map_trials, parser, trials_and_settings

from ccf_ros.core.metrics import summarize
from ccf_ros.engine import ImuEngine
from ccf_ros.offline.bagio import read_bools, read_imu_arrays, read_orientations
from ccf_ros.offline.evaluate import align, engine_orientations, mask_at
from ccf_ros.offline.simulate import dipole_field, generate, with_mag_distortion
from ccf_ros.settings import build

OFFSET_T = np.array([30.0, -12.0, 8.0]) * 1e-6
ON = {'mag_online_calibration': True}


def run_engine(settings: dict, t: np.ndarray, gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray,
               probe_s: float | None = None) -> tuple[np.ndarray, ImuEngine, object]:
    """Orientations (N, 4) [w, x, y, z] of the engine on the arrays (mag NaN rows: no message); the engine; and its
    hard-iron status at ``t[0] + probe_s`` (None if not asked)."""
    eng = ImuEngine(*build(settings))
    t_probe = t[0] + probe_s if probe_s is not None else None
    probe: list[object] = []

    def look(_k: int, t_k: float) -> None:
        if t_probe is not None and not probe and t_k >= t_probe:
            probe.append(eng.hard_iron_status())

    q = engine_orientations(eng, t, gyr, acc, mag, look)
    return q, eng, probe[0] if probe else None


def simulated() -> None:
    d = generate(120.0, 100.0, 3)
    dist = with_mag_distortion(d, OFFSET_T)
    after = d.moving & (d.t_s - d.t_s[0] >= 65.0)  # 60 s of motion after the 5 s rest

    def heading(q: np.ndarray, mask: np.ndarray) -> float:
        return summarize(q, d.q_true, mask).heading_rmse_deg

    q_clean, _, _ = run_engine({}, d.t_s, d.gyr, d.acc, d.mag)
    q_off, _, _ = run_engine({}, dist.t_s, dist.gyr, dist.acc, dist.mag)
    q_on, eng, probe = run_engine(ON, dist.t_s, dist.gyr, dist.acc, dist.mag, probe_s=65.0)
    assert probe is not None
    err = np.linalg.norm(np.array(probe.offset) - OFFSET_T) * 1e6
    print('simulated hand-held motion, 120 s at 100 Hz, seed 3, body-fixed offset (30, -12, 8) uT')
    print(f'  after 60 s of motion: status {probe.status}, applied offset error {err:.3f} uT, '
          f'sigma {" ".join(f"{v * 1e6:.3f}" for v in probe.sigma)} uT, residual {probe.residual_rel:.2%} of the field')
    h = [heading(q, after) for q in (q_clean, q_off, q_on)]
    print(f'  heading RMSE after that (deg): clean {h[0]:.3f}, offset uncorrected {h[1]:.3f}, online on {h[2]:.3f} '
          f'({h[2] / h[0]:.2f}x clean); whole run: clean {heading(q_clean, d.moving):.3f}, '
          f'on {heading(q_on, d.moving):.3f}')
    field = dipole_field([0.25, 0.0, 0.0], [0.0, 0.0, 1.0])
    dp = generate(120.0, 100.0, 3, field=field)
    q_doff, _, _ = run_engine({}, dp.t_s, dp.gyr, dp.acc, dp.mag)
    q_don, eng, _ = run_engine(ON, dp.t_s, dp.gyr, dp.acc, dp.mag)
    s = eng.hard_iron_status()
    assert s is not None
    hd = [summarize(q, dp.q_true, dp.moving).heading_rmse_deg for q in (q_doff, q_don)]
    print(f'  world-fixed dipole (1 A m^2 at 0.25 m), no body offset: status {s.status}, applied offset '
          f'{np.linalg.norm(s.offset) * 1e6:.3f} uT (estimate {np.linalg.norm(s.estimate) * 1e6:.3f} uT), residual '
          f'{s.residual_rel:.2%}; heading off {hd[0]:.3f}, on {hd[1]:.3f} deg')


def run_trial(args: tuple[Path, dict[str, str]]) -> tuple[str, tuple]:
    trial, settings = args
    imu = read_imu_arrays(trial)
    t_ref, q_ref = read_orientations(trial, '/ground_truth/pose')
    mask = mask_at(t_ref, *read_bools(trial, '/ground_truth/moving'))
    out = []
    for extra in ({}, ON):
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
        for name, extra in (('off', {}), ('on', ON)):
            t0 = time.perf_counter()
            run_engine(extra, imu.t_s[:n], imu.gyr[:n], imu.acc[:n], imu.mag[:n])
            times[name].append((time.perf_counter() - t0) / n * 1e6)
    off, on = min(times['off']), min(times['on'])
    print(f'cost ({trial.name[:2]}, {n} samples, best of 3 interleaved, includes this script\'s loop): off {off:.1f} '
          f'us/sample, on {on:.1f} us/sample: {on / off:.2f}x')


def main() -> None:
    ap = parser(__doc__)
    ap.add_argument('--skip-sim', action='store_true')
    a = ap.parse_args()
    if not a.skip_sim:
        simulated()
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
