"""Datasets of the study: IMU arrays plus a reference orientation, from a bag or from the simulator."""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..core import run_batch
from ..core.metrics import error_angles, fill_missing, summarize
from ..core.registry import make_filter
from ..offline.bagio import BagError, read_bools, read_imu_arrays, read_orientations
from ..offline.evaluate import align, mask_at
from ..offline.simulate import SimData


@dataclass
class Dataset:
    """One recording with its reference.

    Attributes:
        name: label in tables and figures.
        t_s: ``(N,)`` IMU stamps, s. gyr: ``(N, 3)`` rad/s. acc: ``(N, 3)`` m/s². mag: ``(N, 3)`` T (NaN: none).
        t_ref: ``(M,)`` reference stamps, s. q_ref: ``(M, 4)`` reference ``[w, x, y, z]`` body->ENU (NaN: lost).
        mask: ``(M,)`` reference samples that are scored (BROAD: the movement mask).
        bias: ``(N, 3)`` true gyro bias, rad/s, when known (simulation), else None.
    """

    name: str
    t_s: np.ndarray
    gyr: np.ndarray
    acc: np.ndarray
    mag: np.ndarray
    t_ref: np.ndarray
    q_ref: np.ndarray
    mask: np.ndarray
    bias: np.ndarray | None = None

    @property
    def rate_hz(self) -> float:
        """Median IMU sample rate, Hz."""
        return float(1.0 / np.median(np.diff(self.t_s)))

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1] - self.t_s[0])


@dataclass(frozen=True)
class Topics:
    """Topic names of a recording (BROAD's layout by default)."""

    imu: str = '/imu/data_raw'
    mag: str = '/imu/mag'
    reference: str = '/ground_truth/pose'
    mask: str | None = '/ground_truth/moving'


def load_bag(path: str | Path, topics: Topics = Topics()) -> Dataset:
    """Read a bag holding IMU, magnetometer, reference orientation and (optional) Bool mask topics."""
    path = Path(path)
    imu = read_imu_arrays(path, topics.imu, topics.mag)
    if len(imu.t_s) < 10:
        raise BagError(f'{path}: fewer than 10 samples on {topics.imu}')
    t_ref, q_ref = read_orientations(path, topics.reference)
    if len(t_ref) == 0:
        raise BagError(f'{path}: no messages on the reference topic {topics.reference}')
    mask = np.ones(len(t_ref), dtype=bool)
    if topics.mask:
        with contextlib.suppress(BagError):  # an optional topic: no mask, every reference sample is scored
            mask = mask_at(t_ref, *read_bools(path, topics.mask))
    return Dataset(path.name, imu.t_s, imu.gyr, imu.acc, imu.mag, t_ref, q_ref, mask)


def from_sim(name: str, sim: SimData) -> Dataset:
    """A simulated recording; the reference is the true orientation at every sample."""
    return Dataset(name, sim.t_s, sim.gyr, sim.acc, sim.mag, sim.t_s, sim.q_true, sim.moving.copy(), sim.bias)


def run_filter(settings: dict[str, Any], ds: Dataset) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Run the filter of ``settings`` over ``ds`` through the core's ``update()``.

    Returns: estimate at the reference stamps ``(M, 4)`` (NaN: none), gyro bias ``(N, 3)`` rad/s, answered ``(N,)``.
    """
    r = run_batch(make_filter(settings), ds.t_s, ds.gyr, ds.acc, ds.mag)
    ok = r.answered
    return align(ds.t_s[ok], r.quat[ok], ds.t_ref, ds.q_ref), r.bias, ok


def total_error_rad(q: np.ndarray, q_ref: np.ndarray) -> np.ndarray:
    """BROAD's total error angle per sample ``(M,)``, rad, of estimates ``q`` against ``q_ref`` (both ``(M, 4)``);
    a missing estimate counts as pi (180°)."""
    filled, missing = fill_missing(q)
    total, _, _ = error_angles(filled, q_ref)
    total[missing] = np.pi
    return total


def score(settings: dict[str, Any], ds: Dataset) -> dict[str, Any]:
    """BROAD metrics (deg) and the paper's (eqs 16-17, rad) of one filter on one dataset."""
    q, _, ok = run_filter(settings, ds)
    s = summarize(q, ds.q_ref, ds.mask)
    return {
        'total_deg': s.total_rmse_deg,
        'heading_deg': s.heading_rmse_deg,
        'inclination_deg': s.inclination_rmse_deg,
        'rmse_rad': list(s.rmse_rad),
        'mean_rmse_rad': s.mean_rmse_rad,
        'n_scored': s.n_scored,
        'n_missing': s.n_missing,
        'n_unanswered': int((~ok).sum()),
    }
