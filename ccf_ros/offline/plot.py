"""Plots of estimate vs reference (the paper's Figs 13-14 style)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..core.metrics import error_angles
from ..core.quaternion import quat_to_euler
from ..errors import CcfError


def plot_rpy(
    path: str | Path,
    t_s: np.ndarray,
    q_ref: np.ndarray,
    estimates: dict[str, np.ndarray],
    title: str = '',
) -> None:
    """Roll, pitch, yaw (deg) of the reference and each estimate over time, plus the total error; PNG."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    t = t_s - t_s[0]
    fig, axes = plt.subplots(4, 1, figsize=(11, 9), sharex=True)
    ref = np.degrees(quat_to_euler(q_ref))
    names = ('roll', 'pitch', 'yaw')
    for i, ax in enumerate(axes[:3]):
        ax.plot(t, ref[:, i], 'k-', lw=1.6, label='reference')
        for label, q in estimates.items():
            ax.plot(t, np.degrees(quat_to_euler(q))[:, i], lw=0.9, label=label)
        ax.set_ylabel(f'{names[i]} [deg]')
        ax.grid(alpha=0.3)
    axes[0].legend(loc='upper right', fontsize=8, ncol=len(estimates) + 1)
    for label, q in estimates.items():
        total, _, _ = error_angles(q, q_ref)
        axes[3].plot(t, np.degrees(total), lw=0.9, label=label)
    axes[3].set_ylabel('total error [deg]')
    axes[3].set_xlabel('time [s]')
    axes[3].grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    save_figure(fig, path)


def check_plot_path(path: str | Path) -> Path:
    """``path`` if its extension is an image type matplotlib writes (checked before any work: the type is known
    only when the figure is saved); :class:`CcfError` otherwise."""
    from matplotlib.backend_bases import FigureCanvasBase

    p = Path(path)
    types = FigureCanvasBase.get_supported_filetypes()
    if p.suffix[1:].lower() not in types:
        raise CcfError(f'cannot write plot {p}: {p.suffix or "no extension"} is not an image type matplotlib writes '
                       f'(choose: {", ".join(f".{t}" for t in sorted(types))})')
    return p


def save_figure(fig: Any, path: str | Path) -> None:
    """Lay out, write (PNG, 90 dpi) and close a matplotlib figure; :class:`CcfError` if the file cannot be written."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    try:
        fig.savefig(path, dpi=90)
    except OSError as err:
        raise CcfError(f'cannot write plot {path}: {err.strerror or err}') from err
    finally:
        plt.close(fig)
