"""The report's Markdown tables, each from the study's results.

Error cells read ``total RMSE (deg) / the paper's mean RMSE (rad)`` (:func:`cell`).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

from .experiments import KI_GRID, KP_GRID, SENSITIVITY_FACTORS, grid_key, sensitivity_key
from .labels import EULER, GRID_CCF, QUATERNION
from .means import mean, method_labels
from .verdicts import CLAIMS


def table(header: list[str], rows: list[list[str]]) -> str:
    """A Markdown table."""
    lines = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
    lines += ['| ' + ' | '.join(r) + ' |' for r in rows]
    return '\n'.join(lines)


def short(name: str) -> str:
    """Column name of a dataset: its BROAD trial number, else its first 12 characters."""
    return name.split('_')[0] if name[:2].isdigit() else name[:12]


def _pair(total_deg: float, mean_rmse_rad: float) -> str:
    return f'{total_deg:.2f} / {mean_rmse_rad:.3f}'


def cell(score: dict[str, Any]) -> str:
    """One score (see :func:`ccf_ros.study.datasets.score`) as ``deg / rad``."""
    return _pair(score['total_deg'], score['mean_rmse_rad'])


def mean_cell(scores: Iterable[dict[str, Any]]) -> str:
    """The mean of several scores as ``deg / rad``."""
    scores = list(scores)
    return _pair(mean(c['total_deg'] for c in scores), mean(c['mean_rmse_rad'] for c in scores))


def verdicts_table(results: dict[str, Any]) -> str:
    """One row per verdict: claim number and text, formulation, verdict, numbers."""
    rows = [[str(v['claim']), CLAIMS[v['claim']], v['formulation'], f'**{v["verdict"]}**', v['text']]
            for v in results['verdicts']]
    return table(['#', 'claim', 'form', 'verdict', 'numbers'], rows)


def grid_table(results: dict[str, Any], form: str, kind: str) -> str:
    """Tables 1-2: one row per (Kp, Ki), one column per dataset, then the mean and std over gains and (CCF only)
    the LSE-fitted gains."""
    names = list(results['grid'])
    header = ['Kp', 'Ki'] + [short(n) for n in names] + ['mean']
    rows = []
    per_gain_deg, per_gain_rad = [], []
    for kp in KP_GRID:
        for ki in KI_GRID:
            cells = [results['grid'][n][grid_key(form, kind, kp, ki)] for n in names]
            per_gain_deg.append([c['total_deg'] for c in cells])
            per_gain_rad.append([c['mean_rmse_rad'] for c in cells])
            rows.append([f'{kp:g}', f'{ki:g}'] + [cell(c) for c in cells] + [mean_cell(cells)])
    deg, rad = np.array(per_gain_deg), np.array(per_gain_rad)
    rows.append(['mean', ''] + [_pair(a, b) for a, b in zip(deg.mean(0), rad.mean(0), strict=True)]
                + [_pair(deg.mean(), rad.mean())])
    # The last column: the spread over gains of the dataset-mean error (what claim 1 is about).
    rows.append(['std', ''] + [_pair(a, b) for a, b in zip(deg.std(0), rad.std(0), strict=True)]
                + [_pair(deg.mean(1).std(), rad.mean(1).std())])
    if kind == GRID_CCF and 'lscf' in results:
        for key, label in (('score', 'adaptive (fit on itself)'), ('loo_score', 'fit on the others')):
            if not all(key in results['lscf'][form][n] for n in names):
                continue
            cells = [results['lscf'][form][n][key] for n in names]
            rows.append(['LSE', label] + [cell(c) for c in cells] + [mean_cell(cells)])
    return table(header, rows)


def sensitivity_table(results: dict[str, Any]) -> str:
    """Table 2b: the ccf_ros CCF with its time constants scaled around the defaults."""
    names = list(results['sensitivity'])
    rows = []
    for fa in SENSITIVITY_FACTORS:
        for fb in SENSITIVITY_FACTORS:
            cells = [results['sensitivity'][n][sensitivity_key(fa, fb)] for n in names]
            rows.append([f'{fa:.3g}', f'{fb:.3g}'] + [cell(c) for c in cells] + [mean_cell(cells)])
    return table(['blends (tau_acc/lp/mag) x', 'NCF (tau_ncf/bias) x'] + [short(n) for n in names] + ['mean'], rows)


def _residuals(fit: dict[str, Any]) -> str:
    return f'{fit["residual_rms_rad_start"]:.4f} -> {fit["residual_rms_rad_end"]:.4f}'


def lscf_table(results: dict[str, Any]) -> str:
    """Table 3: the LSE-fitted gains per dataset, both forms, with a note on how to read them."""
    if 'lscf' not in results:
        return '(LSCF not fitted: run without --no-lscf)'
    rows = []
    for name, fit in results['lscf'][EULER].items():
        rows.append([short(name)] + [f'{v:.3g}' for v in fit['kp']] + [f'{v:.3g}' for v in fit['ki']]
                    + [f'{v:.2f}' for v in fit['alpha']] + [str(fit['filter_runs']), _residuals(fit)])
    t1 = table(['dataset', 'Kp roll', 'Kp pitch', 'Kp yaw', 'Ki roll', 'Ki pitch', 'Ki yaw', 'alpha roll',
                'alpha pitch', 'alpha yaw', 'runs', 'residual RMS, rad'], rows)
    rows = []
    for name, fit in results['lscf'][QUATERNION].items():
        rows.append([short(name), f'{fit["tau_acc_s"]:.3g}', f'{fit["tau_mag_s"]:.3g}', f'{fit["tau_bias_s"]:.3g}',
                     str(fit['filter_runs']), _residuals(fit)])
    t2 = table(['dataset', 'tau_acc_s', 'tau_mag_s', 'tau_bias_s', 'runs', 'residual RMS, rad'], rows)
    note = ('Fits start from the paper\'s gains (euler) and the ccf_ros defaults (quaternion); a fit that found no '
            'better point stays there (same residual before and after). Euler residuals: error rotation vector '
            'components (Euler-angle differences jump at +-90 deg pitch).')
    return f'Paper form (euler), per axis:\n\n{t1}\n\nccf_ros form (quaternion):\n\n{t2}\n\n{note}'


def methods_table(results: dict[str, Any]) -> str:
    """Figs 10-11 as a table: one row per method, one column per dataset ('-': not run there)."""
    names = list(results['methods'])
    rows = []
    for label in method_labels(results):
        cells = [results['methods'][n].get(label) for n in names]
        rows.append([label] + [cell(c) if c else '-' for c in cells] + [mean_cell(c for c in cells if c)])
    return table(['method'] + [short(n) for n in names] + ['mean'], rows)


def compute_time_table(results: dict[str, Any]) -> str:
    """Fig 12 as a table: median time per sample (us) and its ratio to the paper's CCF."""
    ct = results['compute_time']
    return table(['filter', 'median us/sample', 'ratio to CCF (euler)'],
                 [[k, f'{ct["median_us"][k]:.2f}', f'{ct["ratio_to_ccf_euler_median"][k]:.2f}'] for k in ct['median_us']])


def bode_table(results: dict[str, Any]) -> str:
    """Figs 2/4/8 as a table: largest deviation of the measured response from the transfer function, per case."""
    b = results['bode']
    return table(['case', f'max abs. dB error below {b["rate_hz"] / 100:.2f} Hz', 'max abs. phase error, deg'],
                 [[c['label'], f'{c["max_abs_db_error"]:.3f}', f'{c["max_abs_phase_error_deg"]:.2f}'] for c in b['cases']])


def long_run_table(results: dict[str, Any]) -> str:
    """Figs 15-16 as a table: window RMSE (deg) per filter: mean, first, last, max."""
    rows = []
    for label, f in results['long_run']['filters'].items():
        r = f['rmse_total_deg']
        rows.append([label, f'{mean(r):.2f}', f'{r[0]:.2f}', f'{r[-1]:.2f}', f'{max(r):.2f}'])
    return table(['filter', 'mean window RMSE, deg', 'first', 'last', 'max'], rows)
