"""``ccf demo``: simulate a minute of hand-held motion, replay it through the filter, score it and plot it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core import make_filter, run_batch
from ..core.metrics import summarize
from ..engine import ImuEngine
from ..errors import CcfError
from .evaluate import evaluate, load_aligned
from .plot import plot_rpy
from .replay import replay
from .simulate import generate, write_bag


def run_demo(out_dir: Path, duration_s: float = 60.0, seed: int = 1, live: bool = True, live_rate: float = 4.0) -> int:
    """Write ``sim``, ``filtered`` bags and ``demo.png`` into ``out_dir``; print an accuracy table.

    With ``live`` the simulation is also played through a live ``ccf_node`` over loopback DDS.
    """
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise CcfError(f'cannot create {out_dir}: {err.strerror}') from err
    sim_bag = out_dir / 'sim'
    out_bag = out_dir / 'filtered'
    data = generate(duration_s, 286.0, seed)
    write_bag(data, sim_bag, overwrite=True)
    print(f'simulated {duration_s:g} s of hand-held motion at 286 Hz -> {sim_bag}')
    summary = replay(sim_bag, out_bag, ImuEngine(make_filter()), overwrite=True)
    print(f'ccf replay -> {out_bag}: {summary.line()}')
    aligned = load_aligned(out_bag, '/ground_truth/pose', reference_bag=sim_bag, mask_topic='/ground_truth/moving')
    rows = [('ccf replay (offline)', evaluate(aligned))]
    live_ok = True
    if live:
        from .evaluate import align
        from .live import run_live

        print(f'starting ccf_node and playing the simulation into it over loopback DDS at {live_rate:g}x ...')
        res = run_live(sim_bag, rate=live_rate)
        q_live = align(res.t_s, res.quat, aligned.t_s, aligned.q_ref)
        rows.insert(0, ('ccf_node (live, over DDS)', summarize(q_live, aligned.q_ref, aligned.mask)))
        same = np.abs(np.sum(q_live * aligned.q_est, axis=1))
        diff_rad = float(np.nanmax(2 * np.arccos(np.clip(same, 0.0, 1.0)))) if len(res.t_s) else float('nan')
        live_ok = len(res.t_s) == res.n_imu_sent and res.exit_code == 0 and diff_rad < 1e-3
        print(f'ccf_node answered {len(res.t_s)} of {res.n_imu_sent} IMU messages, exit code {res.exit_code}; '
              f'largest difference to replay {diff_rad:.2e} rad')
    # Context: the paper's Euler form and no fusion at all, on the same data.
    euler = run_batch(make_filter({'formulation': 'euler'}), data.t_s, data.gyr, data.acc, data.mag)
    rows.append(('ccf euler, paper gains', summarize(euler.quat, data.q_true, data.moving)))
    print()
    print(f'{"filter":30s} {"total":>8s} {"heading":>8s} {"inclin.":>8s}   (RMSE, deg, moving samples)')
    for label, s in rows:
        print(f'{label:30s} {s.total_rmse_deg:8.2f} {s.heading_rmse_deg:8.2f} {s.inclination_rmse_deg:8.2f}')
    png = out_dir / 'demo.png'
    plot_rpy(png, aligned.t_s, aligned.q_ref, {'ccf (replay)': aligned.q_est, 'ccf euler (paper)': euler.quat},
             title='ccf demo: simulated hand-held motion')
    print(f'\nplot: {png}')
    ok = bool(np.isfinite(aligned.q_est).all()) and rows[0][1].n_missing == 0 and live_ok
    return 0 if ok else 1
