"""Bit-identity and speed of :class:`~ccf_ros.core.ccf.QuaternionCcf` against an earlier revision of the module.

The earlier ``ccf_ros/core/ccf.py`` (a single module, git revision ``--before``) is loaded under another name inside
this run only, beside the current package (both use the current ``core/base.py`` and ``core/quaternion.py``); a
revision where ``ccf`` is a package (``ccf_ros/core/ccf/``, from d617305 on) has its whole ``ccf_ros/core`` loaded
instead (its own ``base.py`` and ``quaternion.py`` too: the comparison then covers the input rules as well), and
both filters run the same samples: the nine BROAD trials at 286 Hz and every 3rd sample, 9-D and 6-D, with defaults
and two sets of non-default parameters; and simulated recordings (jittered stamps at 40 Hz, a field that changes, a
clipping gyro, set_heading / set_gyro_bias / set_params / magnetometer_changed / still_hint mid-run). Every output
(quaternion, NCF quaternion, bias, its sigma, variances, status, rest and disturbance flags, clipped count) must match
bit for bit. Then the core ``update()`` cost per sample on a BROAD trial, before and after interleaved in one run.

Usage: python checks/core_identity.py [--before REV] [--shared DIR] [--no-speed] [--no-identity] [--quick]
       [--reps N]
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from ccf_ros.core import ccf as after
from ccf_ros.offline.bagio import read_imu_arrays
from ccf_ros.offline.simulate import MAG_WORLD, field_change, generate

ROOT = Path(__file__).resolve().parents[1]
#: The shared BROAD trials beside the checkout.
DEFAULT_SHARED = ROOT.parent / 'shared' / 'data' / 'broad'
#: Non-default parameter sets (the ``use_mag`` of a 6-D run is added).
PARAMS: dict[str, dict[str, Any]] = {
    'defaults': {},
    'a': {'gyro_range_rad_s': 4.0, 'mag_consistency_rad': 0.0, 'rest_bias': False, 'mag_ref_learn_s': 0.0},
    'b': {'motion_bias': False, 'tau_acc_s': 0.5, 'tau_mag_s': 5.0, 'tau_bias_s': 20.0, 'mag_reaccept_s': 3.0,
          'mag_norm_tol': 0.02, 'bias_rotation_rad_s': 0.1},
}


def load_before(rev: str, name: str = '_ccf_before') -> ModuleType:
    """The ``ccf`` module of git revision ``rev``: its single-module ``ccf_ros/core/ccf.py`` as module
    ``ccf_ros.core.NAME``, or, where ``ccf`` is a package there, the ``ccf`` of its whole ``ccf_ros/core`` (imported
    as the package ``NAME``: the core imports nothing outside itself)."""
    shown = subprocess.run(['git', '-C', str(ROOT), 'show', f'{rev}:ccf_ros/core/ccf.py'], capture_output=True,
                           text=True)
    if shown.returncode != 0:
        if 'does not exist' not in shown.stderr and 'exists on disk' not in shown.stderr:
            raise SystemExit(f'--before {rev}: {shown.stderr.strip()}')  # e.g. a mistyped revision
        return _load_core_package(rev, name)  # (no ccf.py there: ccf is a package in that revision)
    src = shown.stdout
    path = Path(tempfile.mkdtemp()) / f'{name}.py'
    path.write_text(src)
    spec = importlib.util.spec_from_file_location(f'ccf_ros.core.{name}', path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def _load_core_package(rev: str, name: str) -> ModuleType:
    """``NAME.ccf`` of revision ``rev``'s ``ccf_ros/core`` tree, extracted to a temporary folder as package ``NAME``."""
    root = Path(tempfile.mkdtemp())
    tar = subprocess.run(['git', '-C', str(ROOT), 'archive', rev, 'ccf_ros/core'], check=True, capture_output=True)
    subprocess.run(['tar', '-x', '-C', str(root)], input=tar.stdout, check=True)
    (root / 'ccf_ros' / 'core').rename(root / name)
    spec = importlib.util.spec_from_file_location(name, root / name / '__init__.py',
                                                  submodule_search_locations=[str(root / name)])
    assert spec is not None and spec.loader is not None
    pkg = importlib.util.module_from_spec(spec)
    sys.modules[name] = pkg
    spec.loader.exec_module(pkg)
    return importlib.import_module(f'{name}.ccf')


def record(mod: ModuleType, params: dict[str, Any], t: list[float], g: list[Any], a: list[Any], m: list[Any],
           events: dict[int, str]) -> np.ndarray:
    """Every output of ``mod.QuaternionCcf`` after each sample, as one float array (N, 20); ``events``: index ->
    action taken before that sample."""
    f = mod.QuaternionCcf(mod.CcfParams(**params))
    out = np.full((len(t), 20), np.nan)
    for i in range(len(t)):
        ev = events.get(i)
        if ev == 'heading':
            f.set_heading(0.7)
        elif ev == 'bias':
            f.set_gyro_bias((0.01, -0.02, 0.005), 0.003)
        elif ev == 'params':
            f.set_params(mod.CcfParams(**{**params, 'rest_min_s': 3.0, 'tau_acc_lp_s': 1.5}))
        elif ev == 'magcal':
            f.magnetometer_changed()
        elif ev == 'still':
            f.still_hint = True
        elif ev == 'moving':
            f.still_hint = False
        elif ev == 'reset':
            f.reset()
        s = f.update(t[i], g[i], a[i], m[i])
        row = out[i]
        row[0] = s
        if f.initialized:
            row[1:5] = f.quaternion
            row[5:9] = f.ncf_quaternion
            row[9:12] = f.gyro_bias
            row[12] = f.gyro_bias_sigma_rad_s
            row[13:16] = f.orientation_variance
            row[16] = f.at_rest
            row[17] = f.mag_disturbed
            row[18] = f.n_gyro_clipped
            row[19] = f.flags.heading_absolute
    return out


def compare(job: tuple[str, str, dict[str, Any], tuple[Any, ...], dict[int, str]]) -> tuple[str, int, int, float]:
    """(name, samples, differing samples, largest quaternion difference) of one case, before vs after."""
    name, rev, params, (t, g, a, m), events = job
    before = load_before(rev)
    x = record(before, params, t, g, a, m, events)
    y = record(after, params, t, g, a, m, events)
    same = (x.view(np.uint64) == y.view(np.uint64)).all(axis=1)
    diff = float(np.nanmax(np.abs(x[:, 1:5] - y[:, 1:5]))) if not same.all() else 0.0
    return name, len(t), int((~same).sum()), diff


def as_lists(t: np.ndarray, g: np.ndarray, a: np.ndarray, m: np.ndarray | None) -> tuple[Any, ...]:
    return t.tolist(), g.tolist(), a.tolist(), m.tolist() if m is not None else [None] * len(t)


def jobs(rev: str, shared: Path, quick: bool) -> list[Any]:
    out: list[Any] = []
    trials = sorted(p for p in shared.iterdir() if p.is_dir() and p.name[:2].isdigit()) if shared.is_dir() else []
    for trial in trials[:1] if quick else trials:
        imu = read_imu_arrays(trial)
        for step in (1, 3):
            sl = slice(None, None, step)
            for six_d in (False, True):
                for pname, params in PARAMS.items():
                    if step == 3 and pname != 'defaults':
                        continue
                    p = {**params, 'use_mag': not six_d}
                    data = as_lists(imu.t_s[sl], imu.gyr[sl], imu.acc[sl], None if six_d else imu.mag[sl])
                    out.append((f'{trial.name[:24]} {286 // step}Hz {"6D" if six_d else "9D"} {pname}', rev, p, data,
                                {}))
    d = generate(120.0, 40.0, seed=1)
    jitter = np.sort(d.t_s + np.random.default_rng(0).normal(0.0, 0.02 / 40.0, len(d.t_s)))
    n40 = len(d.t_s)
    events = {n40 // 4: 'heading', n40 // 3: 'bias', n40 // 2: 'params', 2 * n40 // 3: 'magcal',
              3 * n40 // 4: 'still', 3 * n40 // 4 + 200: 'moving', 4 * n40 // 5: 'reset'}
    for pname, params in PARAMS.items():
        out.append((f'sim 40Hz jittered, events {pname}', rev, params, as_lists(jitter, d.gyr, d.acc, d.mag), events))
    fc = generate(120.0, 286.0, seed=2, field=field_change(40.0, 1.3, 0.2, MAG_WORLD), rot_scale=3.0)
    for pname, params in PARAMS.items():
        out.append((f'sim 286Hz field change, fast {pname}', rev, params, as_lists(fc.t_s, fc.gyr, fc.acc, fc.mag), {}))
    b = generate(90.0, 100.0, seed=3, bias_init_rad_s=np.radians(6.0))
    out.append(('sim 100Hz 6 deg/s bias', rev, {}, as_lists(b.t_s, b.gyr, b.acc, b.mag), {}))
    out.append(('sim 100Hz 6 deg/s bias 6D', rev, {'use_mag': False}, as_lists(b.t_s, b.gyr, b.acc, None), {}))
    return out


def speed(rev: str, shared: Path, reps: int) -> None:
    """Core update() per sample (9-D, defaults) on 20000 samples of BROAD trial 07 (its first 30 s rest) or a
    simulation: before, after and a second copy of before (the A/A ratio shows what the machine's noise alone gives)
    interleaved, best of ``reps`` each."""
    before = load_before(rev)
    before2 = load_before(rev, '_ccf_before2')
    trial = shared / '07_undisturbed_fast_rotation_B'
    if trial.is_dir():
        imu = read_imu_arrays(trial)
        t, g, a, m = (x[:20000].tolist() for x in (imu.t_s, imu.gyr, imu.acc, imu.mag))
    else:
        d = generate(70.0, 286.0, seed=4)
        t, g, a, m = (x[:20000].tolist() for x in (d.t_s, d.gyr, d.acc, d.mag))
    n = len(t)

    def loop(mod: ModuleType) -> float:
        u = mod.QuaternionCcf().update
        # CPU time of this process: time spent descheduled by the other processes on the machine does not count.
        t0 = time.process_time()
        for i in range(n):
            u(t[i], g[i], a[i], m[i])
        return (time.process_time() - t0) / n * 1e6

    times: dict[str, list[float]] = {'before': [], 'after': [], 'before2': []}
    mods = {'before': before, 'after': after, 'before2': before2}
    order = list(mods)
    for r in range(reps):
        for k in order[r % 3:] + order[:r % 3]:  # rotated, so that none always runs first or after another
            times[k].append(loop(mods[k]))
    b, a, b2 = (min(times[k]) for k in order)
    print(f'core update() per sample (best of {reps}, interleaved): before {b:.3f} us, after {a:.3f} us, '
          f'before again {b2:.3f} us')
    print(f'after / before = {a / b:.3f} ({a - b:+.3f} us);  A/A: before again / before = {b2 / b:.3f}')


def opcodes(rev: str, shared: Path) -> None:
    """Bytecodes executed per sample (sys.settrace), before and after: a count the machine's load does not blur. On
    3000 samples of BROAD trial 07 (or a simulation) after its first 12000, at 286 Hz and every 12th sample (24 Hz:
    a bias update every sample)."""
    before = load_before(rev)
    trial = shared / '07_undisturbed_fast_rotation_B'
    if trial.is_dir():
        imu = read_imu_arrays(trial)
        data = (imu.t_s, imu.gyr, imu.acc, imu.mag)
    else:
        d = generate(70.0, 286.0, seed=4)
        data = (d.t_s, d.gyr, d.acc, d.mag)

    def count(mod: ModuleType, step: int) -> tuple[float, float]:
        t, g, a, m = (x[::step].tolist() for x in data)
        n0, n = 12000 // step, 3000 // step
        f = mod.QuaternionCcf()
        for i in range(n0):
            f.update(t[i], g[i], a[i], m[i])
        c = [0, 0]

        def trace(frame: Any, event: str, arg: Any) -> Any:
            frame.f_trace_opcodes = True
            c[0 if event == 'opcode' else 1] += event in ('opcode', 'call')
            return trace

        sys.settrace(trace)
        for i in range(n0, n0 + n):
            f.update(t[i], g[i], a[i], m[i])
        sys.settrace(None)
        return c[0] / n, c[1] / n

    for step in (1, 12):
        (ob, cb), (oa, ca) = count(before, step), count(after, step)
        print(f'{286 / step:.0f} Hz: bytecodes per sample before {ob:.1f}, after {oa:.1f} ({oa / ob - 1:+.2%}); '
              f'Python calls per sample before {cb:.2f}, after {ca:.2f}')


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--before', default='30ffc93', help='git revision of the single-module ccf.py (default 30ffc93)')
    ap.add_argument('--shared', type=Path, default=DEFAULT_SHARED, help='folder of the BROAD trials')
    ap.add_argument('--no-speed', action='store_true')
    ap.add_argument('--no-identity', action='store_true')
    ap.add_argument('--quick', action='store_true', help='one BROAD trial only')
    ap.add_argument('--reps', type=int, default=15, help='speed: repetitions of each (default 15)')
    args = ap.parse_args()
    if not args.no_identity:
        t0 = time.time()
        with ProcessPoolExecutor(2) as ex:  # one worker per core of this machine
            results = list(ex.map(compare, jobs(args.before, args.shared, args.quick)))
        bad = 0
        for name, n, n_diff, dq in results:
            print(f'{name:50s} {n:7d} samples  {"bit-identical" if not n_diff else f"{n_diff} DIFFER (max dq {dq:.3g})"}')
            bad += n_diff > 0
        total = sum(r[1] for r in results)
        print(f'{len(results)} cases, {total} samples: {"all bit-identical" if not bad else f"{bad} cases differ"} '
              f'({time.time() - t0:.0f} s)')
    if not args.no_speed:
        opcodes(args.before, args.shared)
        speed(args.before, args.shared, args.reps)
    if not args.no_identity and bad:
        sys.exit(1)


if __name__ == '__main__':
    main()
