"""The report's PNG figures: one function per figure, each drawing it from the study's results."""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .experiments import ALPHA_GRID, alpha_key
from .labels import ACC_MAG_ONLY, CCF_EULER, CCF_QUATERNION, FORMULATIONS, GYRO_ONLY, NCF, REFERENCE
from .means import alpha_means, method_labels
from .tables import short

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def _pyplot() -> Any:
    """pyplot on the file-only backend (no display needed); imported late: only the report draws."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    return plt


def bode_figure(results: dict[str, Any], case_figure: str, title: str) -> Figure:
    """Figs 2/4/8: magnitude and phase of the cases of ``case_figure`` (a figure id of
    :func:`ccf_ros.study.bode.cases`): theory as lines, measured as circles."""
    plt = _pyplot()
    bode = results['bode']
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    for i, c in enumerate(x for x in bode['cases'] if x['figure'] == case_figure):
        color = f'C{i}'
        a1.semilogx(bode['f_theory_hz'], c['theory_db'], color=color, label=c['label'])
        a1.semilogx(bode['f_measured_hz'], c['measured_db'], 'o', color=color, mfc='none')
        a2.semilogx(bode['f_theory_hz'], c['theory_phase_deg'], color=color)
        a2.semilogx(bode['f_measured_hz'], c['measured_phase_deg'], 'o', color=color, mfc='none')
    for ax in (a1, a2):
        ax.axvline(bode['rate_hz'] / 100, color='grey', lw=0.8, ls=':')  # the highest measured frequency
        ax.grid(True, which='both', alpha=0.3)
    a1.set_ylabel('magnitude, dB')
    a2.set_ylabel('phase, deg')
    a2.set_xlabel('frequency, Hz (accelerometer angle -> estimate); o = measured on the implementation')
    a1.set_title(title)
    a1.legend(fontsize=8)
    return fig


def alpha_figure(results: dict[str, Any]) -> Figure:
    """Fig 9: total RMSE (deg, log scale) over alpha per dataset and their mean, one panel per formulation."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for ax, form in zip(axes, FORMULATIONS, strict=True):
        for name, per in results['alpha'].items():
            ax.plot(ALPHA_GRID, [per[alpha_key(form, a)]['total_deg'] for a in ALPHA_GRID], lw=0.8, alpha=0.6,
                    label=short(name))
        ax.plot(ALPHA_GRID, alpha_means(results, form), 'k-o', lw=2, label='mean')
        ax.set_title(f'Fig 9: alpha sweep, Kp=25 Ki=0.1 ({form})')
        ax.set_xlabel('alpha')
        ax.set_ylabel('total RMSE, deg')
        ax.set_yscale('log')
        ax.grid(True, alpha=0.3)
    axes[1].legend(fontsize=7, ncol=2)
    return fig


def methods_figure(results: dict[str, Any], metric: str, ylabel: str, title: str) -> Figure:
    """Figs 10-11: bars of ``metric`` (a key of a score) per method and dataset, plus the mean over datasets."""
    plt = _pyplot()
    names = list(results['methods'])
    labels = method_labels(results)
    fig, ax = plt.subplots(figsize=(12, 4.5))
    width = 0.8 / len(labels)
    x = np.arange(len(names) + 1)
    for i, label in enumerate(labels):
        vals = [results['methods'][n].get(label, {}).get(metric, np.nan) for n in names]
        vals.append(float(np.nanmean(vals)))
        ax.bar(x + (i - len(labels) / 2 + 0.5) * width, vals, width, label=label)
    ax.set_xticks(x, [short(n) for n in names] + ['mean'])
    ax.set_yscale('log')
    ax.set_ylabel(ylabel)
    ax.grid(True, axis='y', alpha=0.3)
    ax.legend(fontsize=7, ncol=5)
    ax.set_title(title)
    return fig


def compute_time_figure(results: dict[str, Any]) -> Figure:
    """Fig 12: time per sample relative to the paper's CCF, bars labelled with the median in us."""
    plt = _pyplot()
    ct = results['compute_time']
    ratios = ct['ratio_to_ccf_euler_median']
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ks = list(ratios)
    ax.bar(ks, [ratios[k] for k in ks], color=['C0', 'C1', 'C2', 'C3'])
    for i, k in enumerate(ks):
        ax.text(i, ratios[k], f'{ct["median_us"][k]:.1f} us', ha='center', va='bottom')
    ax.set_ylabel('time per sample / CCF (euler)')
    ax.set_title(f'Fig 12: compute time, median of {ct["repetitions"]} repetitions')
    ax.tick_params(axis='x', labelsize=7)
    return fig


#: Line styles of the time series; other curves get the default style with their own colour.
_SERIES_STYLES: dict[str, dict[str, Any]] = {
    REFERENCE: {'lw': 2.6, 'color': 'k', 'zorder': 5},
    # drawn over the (thicker) reference: it would be hidden under it
    CCF_QUATERNION: {'lw': 0.9, 'color': 'C1', 'zorder': 6},
    CCF_EULER: {'lw': 0.8, 'color': 'C0', 'zorder': 3},
    ACC_MAG_ONLY: {'lw': 0.6, 'color': '0.6', 'zorder': 1},
    GYRO_ONLY: {'lw': 0.9, 'color': 'C2', 'zorder': 2},
}


def timeseries_figure(results: dict[str, Any], angles: tuple[int, ...], title: str) -> Figure:
    """Figs 13-14: the Euler angles ``angles`` (0 roll, 1 pitch, 2 yaw; deg) over time, one panel each."""
    plt = _pyplot()
    ts = results['timeseries']
    t = np.array(ts['t_s'])
    series = [k for k in ts if k not in ('t_s', 'dataset', REFERENCE)] + [REFERENCE]
    fig, axs = plt.subplots(len(angles), 1, figsize=(11, 3 * len(angles)), sharex=True, squeeze=False)
    for row, ai in enumerate(angles):
        ax = axs[row][0]
        for i, k in enumerate(series):
            y = np.degrees(np.array(ts[k], dtype=float)[:, ai])
            # No vertical lines where the angle wraps at ±180°.
            y[1:][np.abs(np.diff(y)) > 180.0] = np.nan
            ax.plot(t, y, label=k, **_SERIES_STYLES.get(k, {'lw': 0.9, 'color': f'C{i}', 'zorder': 3}))
        ax.set_ylabel(['roll', 'pitch', 'yaw'][ai] + ', deg')
        ax.grid(True, alpha=0.3)
    axs[0][0].legend(fontsize=7, ncol=3)
    axs[0][0].set_title(f'{title}: {ts["dataset"]}')
    axs[-1][0].set_xlabel('time, s')
    return fig


def long_rmse_figure(results: dict[str, Any]) -> Figure:
    """Fig 15: window RMSE (deg, log scale) of each filter over the long run (min)."""
    plt = _pyplot()
    lr = results['long_run']
    fig, ax = plt.subplots(figsize=(10, 4))
    for label, f in lr['filters'].items():
        w = f['window_s']
        ax.plot((np.arange(len(f['rmse_total_deg'])) + 0.5) * w / 60, f['rmse_total_deg'], '-o', ms=3, label=label)
    ax.set_yscale('log')
    ax.set_xlabel('time, min')
    ax.set_ylabel(f'total RMSE per {lr["filters"][NCF]["window_s"]:g} s, deg')
    ax.set_title(f'Fig 15: {lr["duration_s"] / 3600:g} h simulated run, time-varying gyro bias')
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    return fig


def long_bias_figure(results: dict[str, Any]) -> Figure:
    """Fig 16: gyro-bias estimates (deg/s, one value per second) per axis over the long run, with the true bias."""
    plt = _pyplot()
    lr = results['long_run']
    fig, axs = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
    for label, f in lr['filters'].items():
        b = np.degrees(np.array(f['bias_rad_s']))
        if np.nanmax(np.abs(b)) == 0.0:
            continue  # filters without a bias estimate
        tm = np.arange(len(b)) / 60
        for i in range(3):
            axs[i].plot(tm, b[:, i], lw=0.8, label=label)
    truth = next((f.get('true_bias_rad_s') for f in lr['filters'].values() if 'true_bias_rad_s' in f), None)
    if truth is not None:
        b = np.degrees(np.array(truth))
        for i in range(3):
            axs[i].plot(np.arange(len(b)) / 60, b[:, i], 'k', lw=1.5, label='true bias', zorder=5)
    for i in range(3):
        axs[i].set_ylabel(f'{"xyz"[i]} bias, deg/s')
        axs[i].grid(True, alpha=0.3)
    axs[0].legend(fontsize=7, ncol=3)
    axs[0].set_title('Fig 16: gyro-bias estimates over the long run')
    axs[2].set_xlabel('time, min')
    return fig


#: File name and drawing function of every figure, in report order.
FIGURES: tuple[tuple[str, Callable[[dict[str, Any]], Figure]], ...] = (
    ('fig02_lcf.png', partial(bode_figure, case_figure='fig02_lcf', title='Fig 2: LCF (eq 9)')),
    ('fig04_ncf.png', partial(bode_figure, case_figure='fig04_ncf', title='Fig 4: NCF (eq 11)')),
    ('fig08_ccf.png', partial(bode_figure, case_figure='fig08_ccf', title='Fig 8: CCF (eq 15)')),
    ('fig09_alpha.png', alpha_figure),
    ('fig10_methods_broad.png', partial(methods_figure, metric='total_deg', ylabel='total RMSE (BROAD), deg',
                                        title='Fig 10: all methods per dataset')),
    ('fig11_methods_paper.png', partial(methods_figure, metric='mean_rmse_rad', ylabel='mean RMSE (paper eq 17), rad',
                                        title='Fig 11: all methods per dataset')),
    ('fig12_compute_time.png', compute_time_figure),
    ('fig13_timeseries_roll_pitch.png', partial(timeseries_figure, angles=(0, 1), title='Fig 13')),
    ('fig14_timeseries_yaw.png', partial(timeseries_figure, angles=(2,), title='Fig 14')),
)
#: Figures of the long run (only when it ran).
LONG_RUN_FIGURES: tuple[tuple[str, Callable[[dict[str, Any]], Figure]], ...] = (
    ('fig15_long_rmse.png', long_rmse_figure),
    ('fig16_long_bias.png', long_bias_figure),
)


def make_figures(results: dict[str, Any], out_dir: Path) -> list[str]:
    """Write the PNG figures into ``out_dir``; returns their file names."""
    plt = _pyplot()
    files: list[str] = []
    for name, draw in FIGURES + (LONG_RUN_FIGURES if 'long_run' in results else ()):
        fig = draw(results)
        fig.tight_layout()
        fig.savefig(out_dir / name, dpi=110)
        plt.close(fig)
        files.append(name)
    return files
