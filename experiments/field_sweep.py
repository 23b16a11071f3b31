"""Sweep of inhomogeneous magnetic fields (issue 23's arm-chain set: 40 Hz, 67 s, hand-guided): does the 9-D heading
stay within 0.5° of the 6-D heading (one offset fitted each) across fields whose world direction spreads 5-40° RMS?

Each configuration: one or two dipoles (moment M A m², at D m from the workspace's centre, at a random bearing and a
height of ±0.3 D; moment horizontal across the line to the workspace, along it, or vertical), and hand-guided motion
(simulate.generate's hand motion, translation 0.1 m) about a point that wanders per axis as a sine of amplitude A m at
a frequency drawn from a band (the default 0.02-0.08 Hz as wander_path; 'fast': 0.125-0.25 Hz, crossing the
workspace in 2-4 s; 'slow': 0.022-0.028 Hz, ~20 s per crossing). Spreads are of the simulation's true field at the
sensor's position over the moving samples: direction = RMS angle to the mean field's direction; norm = RMS relative
deviation from the mean norm (and 2-98 % range); dip = RMS deviation from the mean dip (and 2-98 % range).

Filter at its defaults (build({}) and build({'use_mag': 'false'})) as simulated_accuracy.run_mag_env; VQF defaults.
Diagnostics from the 9-D filter's own state (per moving sample): share of samples whose field steered heading
(``not mag_disturbed``), the consistency weight's mean while steering, the number of times the gate's reference was
replaced by a new field, and the number of times steering resumed after >= 2 s without.

Usage: python experiments/field_sweep.py [--rate 40] [--seeds 0,1,2] [--only NAME,...] [--rest 5] [--bias-deg 0.5]
       [--spreads] [--per-seed] [--dump FILE.json] [NAME=VALUE ...]   (needs pip install vqf)
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np
from _trials import map_trials
from simulated_accuracy import _heading_rmse

from ccf_ros.core import run_batch
from ccf_ros.core.base import ANSWERED_BELOW
from ccf_ros.core.metrics import summarize
from ccf_ros.offline.simulate import MAG_WORLD, dipole_beside, generate, wander_path
from ccf_ros.settings import build

DURATION_S = 67.0
#: The rest before the motion, s (--rest).
REST_S = [5.0]
#: The gyro's initial bias, rad/s per axis (--bias-deg; None: simulate.generate's 0.5°/s).
BIAS = [None]
BANDS = {'mid': (0.02, 0.08), 'fast': (0.125, 0.25), 'slow': (0.022, 0.028)}

#: name -> (dipoles [(moment A m², distance m, orientation)], wander amplitude m, wander band)
CONFIGS: dict[str, tuple[list[tuple[float, float, str]], float, str]] = {
    'uniform (control)': ([(0, 1.2, 'across')], 0.35, 'mid'),
    'uniform slow (control)': ([(0, 1.2, 'across')], 0.35, 'slow'),
    'ref 300/1.2 across': ([(300, 1.2, 'across')], 0.35, 'mid'),
    '100/2.0 across': ([(100, 2.0, 'across')], 0.35, 'mid'),
    '100/1.2 across': ([(100, 1.2, 'across')], 0.35, 'mid'),
    '300/1.2 along': ([(300, 1.2, 'along')], 0.35, 'mid'),
    '300/1.2 vertical': ([(300, 1.2, 'vertical')], 0.35, 'mid'),
    '600/1.2 across': ([(600, 1.2, 'across')], 0.35, 'mid'),
    '1000/1.2 across': ([(1000, 1.2, 'across')], 0.35, 'mid'),
    '1000/1.2 along': ([(1000, 1.2, 'along')], 0.35, 'mid'),
    '3000/2.0 vertical': ([(3000, 2.0, 'vertical')], 0.35, 'mid'),
    '3000/1.5 across': ([(3000, 1.5, 'across')], 0.35, 'mid'),
    '100/0.6 across A0.2': ([(100, 0.6, 'across')], 0.2, 'mid'),
    '300/1.2 across A0.2': ([(300, 1.2, 'across')], 0.2, 'mid'),
    '300/1.2 across A0.6': ([(300, 1.2, 'across')], 0.6, 'mid'),
    '300/1.2 across fast': ([(300, 1.2, 'across')], 0.35, 'fast'),
    '300/1.2 across slow': ([(300, 1.2, 'across')], 0.35, 'slow'),
    '600/1.2 across fast': ([(600, 1.2, 'across')], 0.35, 'fast'),
    '600/1.2 across slow': ([(600, 1.2, 'across')], 0.35, 'slow'),
    '300/1.2 along slow': ([(300, 1.2, 'along')], 0.35, 'slow'),
    '3000/2.0 across': ([(3000, 2.0, 'across')], 0.35, 'mid'),
    '1000/1.2 across fast': ([(1000, 1.2, 'across')], 0.35, 'fast'),
    '1000/1.2 across slow': ([(1000, 1.2, 'across')], 0.35, 'slow'),
    '100/1.2 across slow': ([(100, 1.2, 'across')], 0.35, 'slow'),
    '30/1.2 across slow': ([(30, 1.2, 'across')], 0.35, 'slow'),
    '200/1.2 across slow': ([(200, 1.2, 'across')], 0.35, 'slow'),
    '100/1.2 along slow': ([(100, 1.2, 'along')], 0.35, 'slow'),
    '100/1.2 vertical slow': ([(100, 1.2, 'vertical')], 0.35, 'slow'),
    '300/2.0 across slow': ([(300, 2.0, 'across')], 0.35, 'slow'),
    '100/1.2 across fast': ([(100, 1.2, 'across')], 0.35, 'fast'),
    '300/1.2 across A0.2 slow': ([(300, 1.2, 'across')], 0.2, 'slow'),
    '2x 300/1.2 across+vert': ([(300, 1.2, 'across'), (300, 1.0, 'vertical')], 0.35, 'mid'),
    '2x 1000/1.5 along+across': ([(1000, 1.5, 'along'), (1000, 1.5, 'across')], 0.35, 'mid'),
}


def make_data(name: str, rate: float, seed: int, rest_s: float | None = None) -> tuple[Any, np.ndarray]:
    """(SimData, the true world field at the sensor (N,3), T)."""
    rest = REST_S[0] if rest_s is None else rest_s
    dipoles, amp, band = CONFIGS[name]
    rng = np.random.default_rng(1000 + seed)
    e = np.asarray(MAG_WORLD, float)
    parts = []
    for m, dist, orient in dipoles:
        parts.append(dipole_beside(rng, m, dist, orient, earth_t=np.zeros(3)))
    seen: dict[str, np.ndarray] = {}

    def field(pos: np.ndarray, t: np.ndarray) -> np.ndarray:
        b = e + sum(p(pos, t) for p in parts)
        seen['b'] = b
        seen['pos'] = pos
        return b

    kw = {} if BIAS[0] is None else {'bias_init_rad_s': BIAS[0]}
    d = generate(DURATION_S, rate, seed, rest_s=rest, translation_m=0.1, field=field, **kw,
                 path_m=wander_path(amp, rng, rest, band_hz=BANDS[band]))
    return d, seen['b']


def spreads(b: np.ndarray, moving: np.ndarray) -> tuple[float, ...]:
    """(direction RMS °, norm RMS %, norm 2-98 % range %, dip RMS °, dip 2-98 % range °) of field b over moving."""
    b = b[moving]
    n = np.linalg.norm(b, axis=1)
    u = b / n[:, None]
    mu = u.mean(axis=0)
    mu /= np.linalg.norm(mu)
    ang = np.degrees(np.arccos(np.clip(u @ mu, -1, 1)))
    dip = np.degrees(np.arcsin(-u[:, 2]))
    rel = n / n.mean()
    p = lambda x: np.percentile(x, 98) - np.percentile(x, 2)  # noqa: E731
    return (float(np.sqrt(np.mean(ang**2))), 100 * float(np.sqrt(np.mean((rel - 1) ** 2))), 100 * float(p(rel)),
            float(np.sqrt(np.mean((dip - dip.mean()) ** 2))), float(p(dip)))


def run_diag(filt: Any, adapter: Any, d: Any) -> tuple[np.ndarray, dict[str, float]]:
    """The 9-D orientations as run_9d gives them (through the engine when mag_online_calibration, as by default),
    recording the gate's state (and the online hard-iron offset applied) per sample."""
    from ccf_ros.engine import ImuEngine
    from ccf_ros.offline.evaluate import engine_orientations

    n = len(d.t_s)
    used = np.zeros(n, bool)
    weight = np.zeros(n)
    hi = np.zeros(n)
    st = {'refs': 0, 'ref': None}
    eng = ImuEngine(filt, adapter) if adapter.mag_online_calibration else None

    def after(k: int, _t: float) -> None:
        used[k] = not filt.mag_disturbed
        weight[k] = filt._mag_weight
        if eng is not None and eng.hard_iron is not None:
            hi[k] = np.linalg.norm(eng.hard_iron.status().offset)
        r = filt._mag_ref
        if st['ref'] is not None and r != st['ref'] and filt._mag_learn_s <= 0.0 and filt._mag_learn_n == 1:
            st['refs'] += 1
        st['ref'] = r

    if eng is not None:
        quat = engine_orientations(eng, d.t_s, d.gyr, d.acc, d.mag, after)
    else:
        quat = np.full((n, 4), np.nan)
        upd = filt._update_floats
        for i, (t, g, a, m) in enumerate(zip(d.t_s.tolist(), d.gyr.tolist(), d.acc.tolist(), d.mag.tolist(),
                                             strict=True)):
            if upd(t, *g, *a, m) < ANSWERED_BELOW:
                quat[i] = filt.quaternion
            after(i, t)
    mv = d.moving
    rate = 1.0 / np.median(np.diff(d.t_s))
    # Resumptions: steering starts again after >= 2 s without.
    resumes = 0
    off_run = 0
    for u in used[mv]:
        if u:
            if off_run >= 2.0 * rate:
                resumes += 1
            off_run = 0
        else:
            off_run += 1
    info = {'used': float(used[mv].mean()), 'w': float(weight[mv][used[mv]].mean()) if used[mv].any() else np.nan,
            'newref': float(st['refs']), 'resume': float(resumes),
            'hi_uT': float(hi[-1] * 1e6)}
    return quat, info


def run_one(args: tuple[str, float, int, dict[str, str], float]) -> tuple[str, float, int, tuple[float, ...], dict]:
    from vqf import VQF

    name, rate, seed, settings, rest, bias = args
    BIAS[0] = bias
    d, b = make_data(name, rate, seed, rest)
    mv = d.moving
    sp = spreads(b, mv)
    f9, a9 = build(settings)
    q9, info = run_diag(f9, a9, d)
    f6, _ = build({**settings, 'use_mag': 'false'})
    q6 = run_batch(f6, d.t_s, d.gyr, d.acc, None).quat
    v = VQF(1.0 / rate).updateBatch(np.ascontiguousarray(d.gyr), np.ascontiguousarray(d.acc),
                                    np.ascontiguousarray(d.mag * 1e6))
    h9 = _heading_rmse(q9, d.q_true, mv, fitted=True)
    h6 = _heading_rmse(q6, d.q_true, mv, fitted=True)
    i9 = summarize(q9, d.q_true, mv).inclination_rmse_deg
    i6 = summarize(q6, d.q_true, mv).inclination_rmse_deg
    v9 = _heading_rmse(v['quat9D'], d.q_true, mv, fitted=True)
    v6 = _heading_rmse(v['quat6D'], d.q_true, mv, fitted=True)
    return name, rate, seed, (*sp, h9, h6, h9 - h6, i9 - i6, v9, v6), info


def run_spreads(args: tuple[str, float, int]) -> tuple[str, float, int, tuple[float, ...]]:
    name, rate, seed = args
    d, b = make_data(name, rate, seed)
    return name, rate, seed, spreads(b, d.moving)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--rate', type=float, default=40.0)
    ap.add_argument('--seeds', default='0,1,2')
    ap.add_argument('--only', default='', help='comma-separated configuration names (default: all)')
    ap.add_argument('--rest', type=float, default=5.0, help='rest before the motion, s (default 5; 0.5: started moving)')
    ap.add_argument('--bias-deg', type=float, default=None, help="gyro's initial bias, °/s per axis (default 0.5)")
    ap.add_argument('--spreads', action='store_true', help='only the field spreads')
    ap.add_argument('--per-seed', action='store_true', help='also print each seed')
    ap.add_argument('--dump', default='', help='write every run (config, seed, figures, diagnostics) to this JSON file')
    ap.add_argument('params', nargs='*', help='NAME=VALUE filter settings')
    a = ap.parse_args()
    try:
        import vqf  # noqa: F401
    except ImportError:
        raise SystemExit('needs the vqf package: pip install vqf') from None
    settings = dict(p.split('=', 1) for p in a.params)
    seeds = [int(s) for s in a.seeds.split(',')]
    names = a.only.split(',') if a.only else list(CONFIGS)
    t0 = time.time()
    if a.spreads:
        res = map_trials(run_spreads, [(n, a.rate, s) for n in names for s in seeds])
        print(f'{"config":26s} dir°  norm%rms/p2p  dip°rms/p2p')
        for n in names:
            m = np.mean([r for nn, _, _, r in res if nn == n], axis=0)
            print(f'{n:26s} {m[0]:5.1f} {m[1]:5.1f}/{m[2]:5.1f} {m[3]:5.1f}/{m[4]:5.1f}')
        print(f'{time.time() - t0:.0f} s')
        return
    res = map_trials(run_one, [(n, a.rate, s, settings, a.rest, None if a.bias_deg is None else np.radians(a.bias_deg)) for n in names for s in seeds])
    if a.dump:
        import json
        Path(a.dump).write_text(json.dumps([[n, r, s, list(x), i] for n, r, s, x, i in res]))
    print(f'rate {a.rate:g} Hz, {DURATION_S:g} s, rest {a.rest:g} s, bias {a.bias_deg or 0.5:g} °/s, seeds {seeds}, settings {settings or "defaults"}; means over seeds '
          '(worst seed of 9-D minus 6-D in brackets)')
    print(f'{"config":26s} {"dir°":>5s} {"norm%":>11s} {"dip°":>11s} | {"ccf9":>5s} {"ccf6":>5s} {"9-6":>5s} '
          f'{"(max)":>6s} {"dInc":>5s} | {"vqf9":>5s} {"vqf6":>5s} | {"used":>4s} {"w":>4s} {"newref":>6s} {"resume":>6s} {"HIµT":>5s}')
    for n in names:
        rows = [(r, i) for nn, _, _, r, i in res if nn == n]
        m = np.mean([r for r, _ in rows], axis=0)
        worst = max(r[7] for r, _ in rows)
        di = {k: np.nanmean([i[k] for _, i in rows]) for k in rows[0][1]}
        flag = ' <-- breaks' if m[7] > 0.5 else ''
        print(f'{n:26s} {m[0]:5.1f} {m[1]:5.1f}/{m[2]:5.1f} {m[3]:5.1f}/{m[4]:5.1f} | {m[5]:5.2f} {m[6]:5.2f} '
              f'{m[7]:+5.2f} ({worst:+5.2f}) {m[8]:+5.2f} | {m[9]:5.2f} {m[10]:5.2f} | {di["used"]:4.2f} '
              f'{di["w"]:4.2f} {di["newref"]:6.1f} {di["resume"]:6.1f} {di["hi_uT"]:5.1f}{flag}')
        if a.per_seed:
            for (r, i), s in zip(rows, seeds, strict=True):
                print(f'   seed {s}: dir {r[0]:5.1f} ccf9 {r[5]:5.2f} ccf6 {r[6]:5.2f} d {r[7]:+5.2f} vqf9 {r[9]:5.2f} '
                      f'vqf6 {r[10]:5.2f} used {i["used"]:4.2f} w {i["w"]:4.2f} newref {i["newref"]:.0f} '
                      f'resume {i["resume"]:.0f} HI {i["hi_uT"]:.1f}')
    print(f'{time.time() - t0:.0f} s')


if __name__ == '__main__':
    main()
