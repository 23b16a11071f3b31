"""The paper's six claims judged on the study's results: one function per claim, each returning a :class:`Verdict`."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .experiments import ALPHA_GRID
from .labels import (
    CCF_LABEL,
    CKF,
    EKF,
    FORMULATIONS,
    GRID_CCF,
    GRID_NCF,
    LSCF_EULER,
    MADGWICK,
    MAHONY,
    NCF,
    NCF_LABEL,
    QUATERNION,
)
from .means import alpha_means, grid_means, lse_mean, mean, method_means, sensitivity_means

#: Thresholds of the verdicts (stated in the report).
FLAT_REL = 0.20  # "barely changes": range of the mean error within 20 % of its median
BETTER_REL = 0.10  # "beats"/"as accurate": more than 10 % apart
COST_RATIO = 5.0  # "much cheaper": at least 5x
DRIFT_REL = 1.25  # "stays accurate": the window RMSE's least-squares trend rises by less than 25 % over the run ...
DRIFT_SE = 2.0  # ... or by less than twice its standard error (the windows' scatter) ...
ACCURATE_DEG = 5.0  # ... and below 5 deg on average

CLAIMS = {
    1: "CCF's error barely changes over Kp x Ki while NCF's changes a lot (Tables 1-2)",
    2: 'LSE-tuned gains do not beat the untuned CCF (Tables 1-3)',
    3: 'alpha from 0.1 to 0.9 hardly matters (Fig 9)',
    4: 'CCF is as accurate as CKF, EKF, LSCF, NCF, Mahony and Madgwick (Figs 10-11)',
    5: 'CCF is much cheaper than CKF and EKF (Fig 12)',
    6: 'CCF stays accurate over 2 hours with a time-varying gyro bias (Figs 15-16)',
}

#: The methods claim 4 compares the CCF with, where measured.
OTHERS = (CKF, EKF, LSCF_EULER, NCF, MAHONY, MADGWICK)


@dataclass(frozen=True)
class Verdict:
    """One claim judged for one formulation.

    Attributes:
        claim: number, a key of :data:`CLAIMS`. formulation: ``'euler'`` or ``'quaternion'``.
        verdict: 'holds', 'does not hold', 'holds only ...' or 'not measured ...'. text: the numbers behind it.
        numbers: the figures the verdict rests on, by name (units in the names), for ``results.json``.
    """

    claim: int
    formulation: str
    verdict: str
    text: str = ''
    numbers: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        """The entry of ``results.json``: claim, formulation, verdict, text, then the numbers."""
        return {'claim': self.claim, 'formulation': self.formulation, 'verdict': self.verdict, 'text': self.text,
                **self.numbers}


def _spread(values: list[float]) -> float:
    return max(values) - min(values)


def _pct(value: float, base: float) -> str:
    """``value`` relative to ``base`` as a signed percentage."""
    return f'{(value / base - 1) * 100:+.0f} %'


def claim1_gain_insensitivity(results: dict[str, Any], form: str) -> Verdict:
    """The CCF's mean error over the 12 gains spans little, in absolute terms and against the NCF's."""
    ccf = grid_means(results, form, GRID_CCF)
    c_vals, n_vals = list(ccf.values()), list(grid_means(results, form, GRID_NCF).values())
    c_range, n_range = _spread(c_vals), _spread(n_vals)
    c_med = float(np.median(c_vals))
    hi_gain = [v for (kp, _), v in ccf.items() if kp >= 1.0]
    hi_range = _spread(hi_gain)
    if c_range <= FLAT_REL * c_med and c_range <= 0.5 * n_range:
        v = 'holds'
    elif hi_range <= FLAT_REL * float(np.median(hi_gain)) and hi_range <= 0.5 * n_range:
        v = f'holds only for Kp >= 1 (range {hi_range:.2f} deg there)'
    elif c_range <= 0.5 * n_range:
        v = 'holds only relative to the NCF: the CCF varies less than the NCF, but not "barely"'
    else:
        v = 'does not hold'
    text = (f'CCF mean total RMSE over the 12 gains: {min(c_vals):.2f}-{max(c_vals):.2f} deg (range '
            f'{c_range:.2f}, median {c_med:.2f}); NCF ({NCF_LABEL[form]}): {min(n_vals):.2f}-{max(n_vals):.2f} '
            f'deg (range {n_range:.2f})')
    if form == QUATERNION and 'sensitivity' in results:
        sens = list(sensitivity_means(results).values())
        text += (f'. Its own time constants x1/3..x3 around the defaults: {min(sens):.2f}-{max(sens):.2f} deg '
                 f'(Table 2b)')
    return Verdict(1, form, v, text, {'ccf_range_deg': c_range, 'ncf_range_deg': n_range, 'ccf_median_deg': c_med})


def claim2_lse_gains(results: dict[str, Any], form: str) -> Verdict:
    """The LSE-fitted CCF is not more accurate than the untuned one, fitted on the dataset itself or the others."""
    lse = lse_mean(results, form)
    if lse is None:
        return Verdict(2, form, 'not measured (run without --no-lscf)')
    untuned = method_means(results)[CCF_LABEL[form]]
    loo = lse_mean(results, form, key='loo_score')
    beats_in = lse < (1.0 - BETTER_REL) * untuned
    beats_out = loo is not None and loo < (1.0 - BETTER_REL) * untuned
    if not beats_in:
        v = 'holds'
    elif loo is not None and not beats_out:
        v = 'holds only on unseen data: fitted on the dataset itself the LSE gains win, fitted on the others not'
    else:
        v = 'does not hold'
    text = (f'LSE fitted on the dataset itself {lse:.2f} deg ({_pct(lse, untuned)})'
            + (f', fitted on the other datasets {loo:.2f} deg ({_pct(loo, untuned)})' if loo else '')
            + f'; untuned {CCF_LABEL[form]} {untuned:.2f} deg')
    return Verdict(2, form, v, text, {'lse_deg': lse, 'lse_loo_deg': loo, 'untuned_deg': untuned})


def claim3_alpha(results: dict[str, Any], form: str) -> Verdict:
    """The mean error over alpha 0.1-0.9 spans little, or stays near its minimum over a run of 3+ alphas."""
    alpha = alpha_means(results, form)
    a_range = _spread(alpha)
    a_med = float(np.median(alpha))
    good = [x for x, v in zip(ALPHA_GRID, alpha, strict=True) if v <= min(alpha) * (1 + FLAT_REL)]
    if a_range <= FLAT_REL * a_med:
        v = 'holds'
    elif len(good) >= 3:
        v = f'holds only for alpha in {min(good):g}-{max(good):g}'
    else:
        v = 'does not hold'
    text = f'mean total RMSE over alpha 0.1-0.9: {min(alpha):.2f}-{max(alpha):.2f} deg (median {a_med:.2f})'
    return Verdict(3, form, v, text, {'alpha_means_deg': alpha})


def claim4_accuracy(results: dict[str, Any], form: str) -> Verdict:
    """No other method is more than :data:`BETTER_REL` more accurate than the CCF."""
    means = method_means(results)
    mine = means[CCF_LABEL[form]]
    others = {k: means[k] for k in OTHERS if k in means}
    better = {k: v for k, v in others.items() if v < (1 - BETTER_REL) * mine}
    worse = {k: v for k, v in others.items() if v > (1 + BETTER_REL) * mine}
    if not better:
        v = 'holds' + (f' (and better than {", ".join(sorted(worse))})' if worse else '')
    else:
        ranked = sorted(better.items(), key=lambda kv: kv[1])
        v = f'does not hold: {", ".join(f"{k} {x:.2f}" for k, x in ranked)} deg are more accurate'
    text = f'{CCF_LABEL[form]} {mine:.2f} deg; ' + ', '.join(f'{k} {x:.2f}' for k, x in others.items())
    return Verdict(4, form, v, text)


def claim5_cost(results: dict[str, Any], form: str) -> Verdict:
    """EKF and CKF take at least :data:`COST_RATIO` times the CCF's time per sample."""
    ratios = results['compute_time']['ratio_to_ccf_euler_median']
    base = ratios[CCF_LABEL[form]]
    r_ekf, r_ckf = ratios[EKF] / base, ratios[CKF] / base
    if min(r_ekf, r_ckf) >= COST_RATIO:
        v = 'holds'
    else:
        v = 'holds for the CKF only' if r_ckf >= COST_RATIO else 'does not hold'
    text = (f'per-sample time: EKF {r_ekf:.1f}x, CKF {r_ckf:.1f}x that of {CCF_LABEL[form]} (medians of '
            f'{results["compute_time"]["repetitions"]} interleaved repetitions)')
    return Verdict(5, form, v, text, {'ekf_ratio': r_ekf, 'ckf_ratio': r_ckf})


#: Claim 6 needs at least this many windows of the long run (its first and last fifths apart).
LONG_RUN_MIN_WINDOWS = 5


def trend_ends(values: list[float]) -> tuple[float, float, float]:
    """The least-squares line through ``values`` (one per window, evenly spaced) at the first and the last window,
    and the standard error of its rise from one to the other (0 with fewer than three values).

    A trend over every window, not the means of two fifths: a filter that tracks the drift has window errors that
    scatter with the motion (0.13-0.34 deg over the 2 h run), and two fifths of that scatter can differ by a third
    either way while the trend is flat."""
    n = len(values)
    if n < 2:
        return values[0], values[0], 0.0
    x = np.arange(n, dtype=float)
    slope, start = np.polyfit(x, values, 1)
    if n < 3:
        return float(start), float(start + slope), 0.0
    resid = np.asarray(values) - (start + slope * x)
    se_slope = math.sqrt(float(resid @ resid) / (n - 2) / float(((x - x.mean()) ** 2).sum()))
    return float(start), float(start + slope * (n - 1)), se_slope * (n - 1)


def claim6_long_run(results: dict[str, Any], form: str) -> Verdict:
    """Over the long run the CCF's window RMSE does not grow and stays below :data:`ACCURATE_DEG` on average."""
    if 'long_run' not in results:
        return Verdict(6, form, 'not measured (--long-run-s 0)')
    filters = results['long_run']['filters']
    mine = filters[CCF_LABEL[form]]
    lr = mine['rmse_total_deg']
    hours = len(lr) * mine['window_s'] / 3600.0
    k = max(1, len(lr) // 5)  # windows in a fifth of the run
    # "Early" skips the first window (when there are others): it holds the start-up convergence.
    first, last = mean(lr[1 : 1 + k] or lr[:k]), mean(lr[-k:])
    mean_lr = mean(lr)
    t0, t1, se = trend_ends(lr[1:] if len(lr) > 1 else lr)
    if len(lr) < LONG_RUN_MIN_WINDOWS:
        # An early and a late fifth that are the same window (or inside the start-up rest) say nothing of drift.
        v = (f'not measured: {len(lr)} window(s) of {mine["window_s"]:g} s; a drift needs at least '
             f'{LONG_RUN_MIN_WINDOWS} (--long-run-s)')
    elif t1 > DRIFT_REL * t0 and t1 - t0 > DRIFT_SE * se:
        v = 'does not hold: the error grows'
    elif mean_lr > ACCURATE_DEG:
        v = f'does not hold: no drift, but {mean_lr:.1f} deg throughout'
    else:
        v = f'holds (over {hours:.3g} h)'
    per_filter = '; '.join(f'{label} {mean(f["rmse_total_deg"]):.2f} (last fifth {mean(f["rmse_total_deg"][-k:]):.2f})'
                      for label, f in filters.items())
    text = (f'{CCF_LABEL[form]}: RMSE per {mine["window_s"]:g} s window {first:.2f} deg early, {last:.2f} deg in the '
            f'last fifth, max {max(lr):.2f}; trend {t0:.2f} -> {t1:.2f} deg (standard error of the rise {se:.2f}). '
            'Means: ' + per_filter)
    return Verdict(6, form, v, text)


#: The claims in report order.
CLAIM_CHECKS: tuple[Callable[[dict[str, Any], str], Verdict], ...] = (
    claim1_gain_insensitivity, claim2_lse_gains, claim3_alpha, claim4_accuracy, claim5_cost, claim6_long_run,
)


def verdicts(results: dict[str, Any]) -> list[Verdict]:
    """Every claim for each formulation, formulation by formulation."""
    return [check(results, form) for form in FORMULATIONS for check in CLAIM_CHECKS]
