"""Orchestration of ``ccf study``: datasets and experiments in a process pool, a progress bar, then the report."""

from __future__ import annotations

import importlib.util
import math
import os
import signal
import sys
import time
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import CcfError, ParameterError
from ..offline.simulate import generate
from . import experiments as ex
from . import lscf
from .bode import bode_study
from .datasets import Dataset, Topics, from_sim, load_bag
from .labels import CKF, EKF, EULER, FORMULATIONS, LSCF_EULER


@dataclass(frozen=True)
class StudyOptions:
    """What ``ccf study`` runs.

    Attributes:
        long_run_s: duration of the simulated long run (Figs 15-16), s; 0 skips it. Default 7200 (2 h).
        long_run_rate_hz: its sample rate, Hz. Default 100.
        jobs: worker processes. Default: number of CPUs.
        lscf: fit the LSCF gains (needs scipy). Default True.
        lscf_iterations: least-squares iterations per fit. Default 8.
        repetitions: timing repetitions for Fig 12. Default 20 (the paper's).
        bode_frequencies: measured frequencies per Bode case. Default 7.
        seed: seed of the simulations.
    """

    long_run_s: float = 7200.0
    long_run_rate_hz: float = 100.0
    jobs: int = 0
    lscf: bool = True
    lscf_iterations: int = 8
    repetitions: int = 20
    bode_frequencies: int = 7
    seed: int = 7

    def __post_init__(self) -> None:
        # Written as "ok" conditions so that NaN fails them.
        for name, ok, rule in (
            ('long_run_s', self.long_run_s >= 0, '>= 0'),
            ('long_run_rate_hz', self.long_run_rate_hz > 0, '> 0'),
            ('repetitions', self.repetitions >= 1, '>= 1'),
            ('jobs', self.jobs >= 0, '>= 0 (0: one per CPU)'),
            ('lscf_iterations', self.lscf_iterations >= 1, '>= 1'),
            ('bode_frequencies', self.bode_frequencies >= 1, '>= 1'),
        ):
            if not ok:
                raise ParameterError(f'{name} must be {rule}, got {getattr(self, name)!r}')


#: Gyro bias of the long run (a consumer MEMS gyro): initial N(0, 0.5°/s) per axis, thermal drift of ±0.3°/s over
#: an hour, rate random walk 2e-5 rad/s/√s (0.07°/s after 2 h). Pure rotation, no linear acceleration: the run
#: measures the bias claim; linear accelerations are what BROAD's trials measure.
LONG_RUN_BIAS: dict[str, float] = {
    'translation_m': 0.0,
    'bias_init_rad_s': math.radians(0.5),
    'bias_drift_rad_s': math.radians(0.3),
    'bias_drift_period_s': 3600.0,
    'bias_walk_rad_s_sqrt_s': 2e-5,
}


def long_run_dataset(opts: StudyOptions) -> Dataset:
    """The simulated long run: gentle rotations (±40°) with the time-varying bias of :data:`LONG_RUN_BIAS`."""
    b = LONG_RUN_BIAS
    sim = generate(
        opts.long_run_s, opts.long_run_rate_hz, seed=opts.seed, rot_scale=0.5, rest_s=30.0,
        translation_m=b['translation_m'], bias_init_rad_s=b['bias_init_rad_s'],
        bias_drift_rad_s=b['bias_drift_rad_s'], bias_drift_period_s=b['bias_drift_period_s'],
        bias_walk_rad_s_sqrt_s=b['bias_walk_rad_s_sqrt_s'],
    )
    return from_sim(f'simulated {opts.long_run_s / 3600:g} h', sim)


def _ignore_sigint() -> None:
    """Workers leave Ctrl-C to the parent, which stops them (no traceback per worker)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


#: A pool task: its key in the results, the function, its arguments.
Task = tuple[str, Callable[..., Any], tuple[Any, ...]]


# Task functions run in worker processes; module level so that they pickle.
def _task_load(path: str, topics: Topics) -> Dataset:
    return load_bag(path, topics)


def _task_lscf(form: str, ds: Dataset, iterations: int) -> dict[str, Any]:
    fit = lscf.fit_euler(ds, iterations) if form == EULER else lscf.fit_quaternion(ds, iterations)
    fit['score'] = ex.score(fit['settings'], ds)
    return fit


def _task_long(opts: StudyOptions, label: str) -> dict[str, Any]:
    return ex.long_run(long_run_dataset(opts), label)


def _run_pool(jobs: int, tasks: Sequence[Task], desc: str, progress: bool) -> dict[str, Any]:
    """Run ``(key, function, args)`` tasks in a process pool with a progress bar; results by key."""
    from tqdm import tqdm

    results: dict[str, Any] = {}
    with ProcessPoolExecutor(max_workers=jobs, initializer=_ignore_sigint) as pool:
        futures: dict[Future[Any], str] = {pool.submit(fn, *args): key for key, fn, args in tasks}
        bar = tqdm(total=len(futures), desc=desc, unit='task', disable=not progress, file=sys.stderr)
        try:
            pending = set(futures)
            while pending:
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for fut in done:
                    try:
                        results[futures[fut]] = fut.result()
                    except CcfError:
                        raise  # the user's input (a bag, a parameter): its message says what is wrong
                    except Exception as err:
                        # A bug: the worker's traceback is chained (concurrent.futures' _RemoteTraceback).
                        raise RuntimeError(f'study task {futures[fut]} failed: {type(err).__name__}: {err}') from err
                    bar.set_postfix_str(futures[fut][:40])
                    bar.update()
        except BaseException:
            # Ctrl-C or a failed task: stop now rather than after the running tasks (minutes). The pool has no
            # public way to stop a running task, hence its process table.
            for fut in futures:
                fut.cancel()
            for proc in list(getattr(pool, '_processes', {}).values()):
                proc.terminate()
            pool.shutdown(wait=True, cancel_futures=True)
            raise
        finally:
            bar.close()
    return results


def _lscf_key(form: str, name: str) -> str:
    return f'lscf_{form}/{name}'


def _load_datasets(bags: Sequence[str | Path], topics: Topics, jobs: int, progress: bool) -> list[Dataset]:
    """The bags' datasets in the order given, with unique names."""
    loaded = _run_pool(jobs, [(str(b), _task_load, (str(b), topics)) for b in bags], 'loading bags', progress)
    datasets = [loaded[str(b)] for b in bags]
    names = [d.name for d in datasets]
    if len(set(names)) != len(names):
        # Same folder name in different places: make labels unique.
        for i, d in enumerate(datasets):
            d.name = f'{i + 1:02d}_{d.name}'
    return datasets


def _experiment_tasks(datasets: list[Dataset], opts: StudyOptions) -> list[Task]:
    """Every experiment of every dataset, the long run's filters, the Bode study and the time series."""
    tasks: list[Task] = []
    # Longest first, so that two workers finish together.
    slow_long = (CKF, EKF)
    if opts.long_run_s > 0:
        tasks += [(f'long/{label}', _task_long, (opts, label)) for label in slow_long]
    for d in datasets:
        if opts.lscf:
            tasks += [(_lscf_key(form, d.name), _task_lscf, (form, d, opts.lscf_iterations)) for form in FORMULATIONS]
        tasks.append((f'grid/{d.name}', ex.gain_grid, (d,)))
        tasks.append((f'methods/{d.name}', ex.methods, (d,)))
        tasks.append((f'alpha/{d.name}', ex.alpha_sweep, (d,)))
        tasks.append((f'sensitivity/{d.name}', ex.default_sensitivity, (d,)))
    if opts.long_run_s > 0:
        tasks += [(f'long/{label}', _task_long, (opts, label)) for label in ex.LONG_RUN_FILTERS if label not in slow_long]
    tasks.append(('bode', bode_study, (datasets[0].rate_hz, opts.bode_frequencies)))
    tasks.append(('timeseries', ex.time_series, (datasets[0],)))
    return tasks


def _leave_one_out(datasets: list[Dataset], res: dict[str, Any], jobs: int, progress: bool) -> dict[str, Any]:
    """Each dataset scored with the LSE gains pooled from the others' fits; keys ``form/name``."""
    fits = {form: {d.name: res[_lscf_key(form, d.name)] for d in datasets} for form in FORMULATIONS}
    tasks: list[Task] = [
        (f'{form}/{d.name}', ex.score, (lscf.pooled_settings(form, [f for n, f in fits[form].items() if n != d.name]), d))
        for form in FORMULATIONS
        for d in datasets
    ]
    return _run_pool(jobs, tasks, 'LSE leave-one-out', progress)


def _collect(
    datasets: list[Dataset], res: dict[str, Any], loo: dict[str, Any] | None, timing: dict[str, Any],
    opts: StudyOptions, jobs: int,
) -> dict[str, Any]:
    """The study's results from the tasks' (``res``; ``loo``: leave-one-out scores, None if not run)."""

    def per_dataset(experiment: str) -> dict[str, Any]:
        return {d.name: res[f'{experiment}/{d.name}'] for d in datasets}

    out: dict[str, Any] = {
        'datasets': [
            {'name': d.name, 'samples': len(d.t_s), 'rate_hz': d.rate_hz, 'duration_s': d.duration_s,
             'scored': int(d.mask.sum())}
            for d in datasets
        ],
        'grid': per_dataset('grid'),
        'alpha': per_dataset('alpha'),
        'sensitivity': per_dataset('sensitivity'),
        'methods': per_dataset('methods'),
        'bode': res['bode'],
        'timeseries': res['timeseries'],
        'compute_time': timing,
        'options': opts.__dict__ | {'jobs': jobs},
    }
    if opts.lscf:
        out['lscf'] = {form: {d.name: res[_lscf_key(form, d.name)] for d in datasets} for form in FORMULATIONS}
        for d in datasets:
            out['methods'][d.name][LSCF_EULER] = out['lscf'][EULER][d.name]['score']
        if loo is not None:
            for form in FORMULATIONS:
                for d in datasets:
                    out['lscf'][form][d.name]['loo_score'] = loo[f'{form}/{d.name}']
    if opts.long_run_s > 0:
        out['long_run'] = {
            'duration_s': opts.long_run_s,
            'rate_hz': opts.long_run_rate_hz,
            'model': dict(LONG_RUN_BIAS, rot_scale=0.5, rest_s=30.0, seed=opts.seed),
            'filters': {label: res[f'long/{label}'] for label in ex.LONG_RUN_FILTERS},
        }
    return out


def run_study(
    bags: Sequence[str | Path],
    opts: StudyOptions | None = None,
    *,
    topics: Topics | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Every experiment on every bag (plus the long simulated run); all numbers in one JSON-able dict."""
    opts = opts or StudyOptions()
    topics = topics or Topics()
    t_start = time.time()
    jobs = opts.jobs or os.cpu_count() or 1
    if not bags:
        raise CcfError('no bags given')
    if opts.lscf and importlib.util.find_spec('scipy') is None:
        # Before the slow part, not after: the fit needs scipy, the rest of the study does not.
        raise CcfError('the LSCF fit needs scipy: pip install "ccf_ros[study]", or pass --no-lscf')
    datasets = _load_datasets(bags, topics, jobs, progress)
    res = _run_pool(jobs, _experiment_tasks(datasets, opts), 'experiments', progress)
    loo = _leave_one_out(datasets, res, jobs, progress) if opts.lscf and len(datasets) > 1 else None
    # Timing alone, after the pool: nothing of ours competes for the CPU.
    if progress:
        print(f'timing CCF, EKF, CKF ({opts.repetitions} repetitions) ...', file=sys.stderr)
    timing = ex.compute_time(datasets[0], opts.repetitions)
    out = _collect(datasets, res, loo, timing, opts, jobs)
    out['wall_time_s'] = time.time() - t_start
    return out
