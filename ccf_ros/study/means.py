"""Means over datasets, read from the results of :func:`ccf_ros.study.run.run_study` (verdicts, tables, figures)."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

from .experiments import ALPHA_GRID, KI_GRID, KP_GRID, alpha_key, grid_key


def mean(values: Iterable[float]) -> float:
    """Mean; NaN for no values (a table cell without data)."""
    values = list(values)
    return float(np.mean(values)) if values else float('nan')


def grid_means(results: dict[str, Any], form: str, kind: str, metric: str = 'total_deg') -> dict[tuple[float, float], float]:
    """Mean over datasets of ``metric`` for every (Kp, Ki) of the grid."""
    return {
        (kp, ki): mean(g[grid_key(form, kind, kp, ki)][metric] for g in results['grid'].values())
        for kp in KP_GRID
        for ki in KI_GRID
    }


def alpha_means(results: dict[str, Any], form: str) -> list[float]:
    """Mean total RMSE (deg) over datasets at each alpha of :data:`ALPHA_GRID` (Fig 9)."""
    return [mean(per[alpha_key(form, a)]['total_deg'] for per in results['alpha'].values()) for a in ALPHA_GRID]


def sensitivity_means(results: dict[str, Any]) -> dict[str, float]:
    """Mean total RMSE (deg) over datasets per ``f_blend/f_ncf`` key of the default-sensitivity grid."""
    keys = next(iter(results['sensitivity'].values())).keys()
    return {k: mean(v[k]['total_deg'] for v in results['sensitivity'].values()) for k in keys}


def lse_mean(results: dict[str, Any], form: str, metric: str = 'total_deg', key: str = 'score') -> float | None:
    """Mean over datasets of the LSE-fitted CCF's ``metric``: ``key='score'`` fitted on the dataset itself,
    ``'loo_score'`` fitted on the other datasets (None if not measured)."""
    if 'lscf' not in results or not all(key in v for v in results['lscf'][form].values()):
        return None
    return mean(v[key][metric] for v in results['lscf'][form].values())


def method_labels(results: dict[str, Any]) -> list[str]:
    """Every method label of the results, in first-seen order (LSCF exists only where it was fitted)."""
    labels: list[str] = []
    for per in results['methods'].values():
        labels += [k for k in per if k not in labels]
    return labels


def method_means(results: dict[str, Any], metric: str = 'total_deg') -> dict[str, float]:
    """Mean of ``metric`` per method label over the datasets that have it."""
    labels = method_labels(results)
    return {k: mean(per[k][metric] for per in results['methods'].values() if k in per) for k in labels}
