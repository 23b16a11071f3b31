"""What the BROAD benchmark scripts share: the ``--shared`` / ``NAME=VALUE`` command line, the trial list, and one
worker per core over the trials."""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

#: The shared BROAD trials beside the checkout.
DEFAULT_SHARED = Path(__file__).resolve().parents[2] / 'shared' / 'data' / 'broad'


def parser(doc: str, trials: str = '') -> argparse.ArgumentParser:
    """An argument parser with ``--shared DIR``, ``--trials NN,NN`` (default ``trials``; empty: all) and
    ``NAME=VALUE ...`` filter settings; add more before parsing."""
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--shared', type=Path, default=DEFAULT_SHARED, help='folder of the BROAD trials')
    ap.add_argument('--trials', default=trials,
                    help=f'comma-separated trial numbers, e.g. 02,11 (default: {trials or "all"})')
    ap.add_argument('params', nargs='*', help='NAME=VALUE filter settings')
    return ap


def trials_and_settings(args: argparse.Namespace) -> tuple[list[Path], dict[str, str]]:
    """The trial folders (sorted, those named NN_..., only the numbers of ``args.trials`` if given) in ``args.shared``
    and the settings of ``args.params``."""
    trials = sorted(p for p in args.shared.iterdir() if p.is_dir() and p.name[:2].isdigit())
    if args.trials:
        keep = set(args.trials.split(','))
        trials = [t for t in trials if t.name[:2] in keep]
    return trials, dict(p.split('=', 1) for p in args.params)


def map_trials(fn: Callable[[Any], Any], jobs: Iterable[Any]) -> list[Any]:
    """``fn`` over ``jobs`` in two worker processes (this machine's cores), results in order."""
    with ProcessPoolExecutor(2) as ex:
        return list(ex.map(fn, jobs))


def run_9d(filt: Any, adapter: Any, t: Any, gyr: Any, acc: Any, mag: Any) -> tuple[Any, Any]:
    """(quat (N,4), answered (N,) bool) of ``filt`` on the arrays: through the core's ``run_batch``, or, when the
    engine adds something to the filter (``mag_online_calibration``: the online hard iron lives in the engine), through
    the engine as ``ccf replay`` runs it (a NaN row of ``mag``: no magnetometer message)."""
    import numpy as np

    from ccf_ros.core import run_batch
    from ccf_ros.engine import ImuEngine
    from ccf_ros.offline.evaluate import engine_orientations

    if mag is None or not adapter.mag_online_calibration:
        r = run_batch(filt, t, gyr, acc, mag)
        return r.quat, r.answered
    q = engine_orientations(ImuEngine(filt, adapter), t, gyr, acc, mag)
    return q, np.all(np.isfinite(q), axis=1)
