"""IMU health of one bag, computed while the bag streams through the engine (running sums over blocks of samples:
memory does not grow with the bag's length).

Every metric, its method, threshold and the threshold's source are listed in doc/fleet.md; the thresholds are the
constants below. A bag's ``health`` is the worst level of its flags: ``ok`` (none), ``warn`` or ``fail``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core import CcfParams

__all__ = ['FLAGS', 'HealthAccumulator', 'Thresholds', 'judge']

G_M_S2 = 9.80665
NAN3 = (math.nan, math.nan, math.nan)

#: The flag vocabulary: name -> what it means. A bag's ``flags`` are a subset, in this order.
FLAGS = {
    'samples_dropped': 'gaps in the IMU stamps: samples missing at the nominal rate',
    'stamps_not_increasing': 'IMU stamps repeated or going backwards',
    'gyro_clipping': 'gyro flat-topped at its largest |value| (the sensor range)',
    'acc_clipping': 'accelerometer flat-topped at its largest |value| (the sensor range)',
    'gyro_bias_high': 'gyro offset at rest beyond what a healthy MEMS gyro shows',
    'gyro_bias_unstable': 'gyro offset at rest changes within the bag',
    'acc_norm_off': 'accelerometer norm at rest differs from g (scale or offset error)',
    'vibration_high': 'high-frequency accelerometer vibration (above 5 Hz)',
    'mag_disturbed': "the field's norm varies (a magnet, steel, currents, or an uncalibrated hard iron)",
    'filter_nonfinite': 'the filter state became non-finite (NaN) and was re-initialised',
    'filter_restarts': 'the filter restarted after clock jumps',
    'gyro_only_high': 'a large share of samples propagated gyro-only (accelerometer unusable)',
}


@dataclass(frozen=True)
class Thresholds:
    """Flag thresholds: ``(warn, fail)`` per metric, in the metric's unit (see doc/fleet.md for the sources)."""

    dropped_share: tuple[float, float] = (1e-3, 0.05)
    not_increasing_share: tuple[float, float] = (0.0, 0.01)
    clip_samples: tuple[float, float] = (5, 100)
    gyro_bias_rad_s: tuple[float, float] = (math.radians(2.0), math.radians(10.0))
    gyro_bias_change_rad_s: tuple[float, float] = (math.radians(1.0), math.radians(5.0))
    acc_norm_error_share: tuple[float, float] = (0.04, 0.10)
    vibration_m_s2: tuple[float, float] = (15.0, 30.0)
    mag_norm_cv: tuple[float, float] = (0.06, 0.15)
    gyro_only_share: tuple[float, float] = (0.10, 0.5)
    #: |gyro| (rad/s) and |acc| (m/s²) below which a flat top is not a range limit: below the smallest common full
    #: scale (±125 °/s = 2.18 rad/s; ±2 g = 19.6 m/s²), with margin for the sensor's own bias.
    gyro_range_min_rad_s: float = 2.0
    acc_range_min_m_s2: float = 15.0


#: A window is at rest when every axis' standard deviation within it is below these (gyro rad/s, acc m/s²): a
#: hand-held or driving IMU moves more; a MEMS IMU's noise over 0.5 s is far less (~0.005 rad/s, ~0.05 m/s²).
REST_GYRO_STD_RAD_S = 0.02
REST_ACC_STD_M_S2 = 0.2
#: ... and its mean rate, per axis, one a gyro offset can be: within the filter's bias clamp (the core's rest test
#: asks the same of its low-passed gyro). A steady turn faster than that (a robot spinning in place) is no rest.
REST_BIAS_MAX_RAD_S = CcfParams().bias_max_rad_s
#: Rest windows this long in all at least, s, before the offset and the accelerometer norm are read from them: a
#: single window of gentle hand motion at a near-constant rate passes as rest (one read 15 °/s of "offset"). A bag
#: without that much rest, but whose windows as steady as at rest read on average a rate beyond the clamp (on one
#: axis) for as long: a gyro offset beyond it (a still IMU), or a turn in one direction at a steady rate; without a
#: rest the two look alike, and either is flagged ``gyro_bias_high`` (the filter cannot learn such an offset). Turns
#: back and forth average out.
REST_MIN_S = 2.0
#: Rest windows, s; vibration windows, s (the window mean removed: a high-pass at about 1/window = 5 Hz, the band
#: ArduPilot's VIBE and PX4 look at).
REST_WINDOW_S = 0.5
VIBRATION_WINDOW_S = 0.2
#: Relative tolerance of "at the peak" for clipping (a clipped sensor repeats its extreme value exactly).
CLIP_TOLERANCE = 1e-4
#: Samples collected before a block is reduced to running sums.
BLOCK = 4096


class _Peak:
    """Per-axis largest |value| so far and the number of samples at it (within :data:`CLIP_TOLERANCE`)."""

    def __init__(self) -> None:
        self.peak = np.zeros(3)
        self.count = np.zeros(3, dtype=np.int64)

    def add(self, x: np.ndarray) -> None:
        a = np.abs(x)
        bmax = a.max(axis=0)
        for k in range(3):
            if bmax[k] > self.peak[k] * (1.0 + CLIP_TOLERANCE):
                self.peak[k] = bmax[k]
                self.count[k] = int(np.count_nonzero(a[:, k] >= bmax[k] * (1.0 - CLIP_TOLERANCE)))
            elif bmax[k] >= self.peak[k] * (1.0 - CLIP_TOLERANCE):
                self.count[k] += int(np.count_nonzero(a[:, k] >= self.peak[k] * (1.0 - CLIP_TOLERANCE)))

    def clipped(self, range_min: float) -> int:
        """Samples flat-topped at a peak that could be a sensor range (0 if none)."""
        return int(sum(int(c) for p, c in zip(self.peak, self.count, strict=True) if p >= range_min and c > 1))


class HealthAccumulator:
    """Collects IMU samples (:meth:`add`) and reduces them block by block; :meth:`result` gives the metrics."""

    def __init__(self) -> None:
        self._buf: list[tuple[float, Sequence[float], Sequence[float], Any, bool]] = []
        self.add = self._buf.append  # (t_s, gyr, acc, mag or None, mag rejected by the gate)
        self._parts: list[tuple[np.ndarray, ...]] = []  # add_block's samples not reduced yet
        self._n_parts = 0
        self.n = 0
        self.t_first = math.nan
        self.t_last = math.nan
        self._dt_nominal = math.nan
        self._n_not_increasing = 0
        self._n_gaps = 0
        self._max_gap_s = 0.0
        self._jit = np.zeros(3)  # count, sum, sum of squares of regular dt, s
        self._gyro_peak = _Peak()
        self._acc_peak = _Peak()
        self._rest_n = 0  # rest windows
        self._steady_fast_n = 0  # windows steady as at rest, at a mean rate beyond the bias clamp
        self._steady_fast_gyr = np.zeros(3)  # sum of their means
        self._rest_gyr = np.zeros(3)  # sum of window means
        self._rest_gyr_var = 0.0  # sum of window variances (mean over axes)
        self._rest_acc_norm = 0.0
        self._rest_first: np.ndarray | None = None
        self._rest_last: np.ndarray | None = None
        self._vib = np.zeros(4)  # windows, sum of squared high-passed acc per axis
        self._vib_n = 0
        self._vib_max = 0.0
        self._mag_n = 0
        self._mag_rejected = 0
        self._mag = np.zeros(4)  # count of norms, sum, sum of squares; (unused slot)
        self._dip = np.zeros(3)  # count, sum, sum of squares, rad
        self._ata = np.zeros((4, 4))  # sphere fit normal equations: [m, 1] -> |m|²
        self._aty = np.zeros(4)
        self._dir = np.zeros((3, 3))  # sum of unit-direction outer products
        self._dir_sum = np.zeros(3)

    def flush(self) -> None:
        """Reduce the collected samples to running sums (called every :data:`BLOCK` samples and at the end)."""
        buf = self._buf
        if not buf:
            return
        t = np.fromiter((b[0] for b in buf), float, len(buf))
        gyr = np.array([b[1] for b in buf], dtype=float).reshape(-1, 3)
        acc = np.array([b[2] for b in buf], dtype=float).reshape(-1, 3)
        mag = np.array([b[3] if b[3] is not None else NAN3 for b in buf], dtype=float).reshape(-1, 3)
        rejected = np.fromiter((b[4] for b in buf), bool, len(buf))
        buf.clear()
        self._reduce(t, gyr, acc, mag, rejected)

    def observe(self, engine: Any) -> None:
        """Route every IMU sample ``engine`` gets through :meth:`add` too (its ``on_imu`` is wrapped, for this
        engine only), with the paired magnetometer sample and the gate's verdict after the sample."""
        on_imu = engine.on_imu
        add, buf, filt = self.add, self._buf, engine.filter
        gated = hasattr(filt, 'mag_disturbed')

        def observed(t_s: float, gyr: Any, acc: Any) -> Any:
            out = on_imu(t_s, gyr, acc)
            add((t_s, gyr, acc, engine.paired_mag, gated and filt.mag_disturbed))
            if len(buf) >= BLOCK:
                self.flush()
            return out

        engine.on_imu = observed

    def add_block(self, t: np.ndarray, gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray, rejected: np.ndarray) -> None:
        """Samples as arrays: stamps (N,) s, gyr (N, 3) rad/s, acc (N, 3) m/s², paired mag (N, 3) (NaN: none),
        rejected by the gate (N,); the same metrics as :meth:`add` for each, reduced in the same blocks of
        :data:`BLOCK` samples (so the figures are equal to the last bit). Do not mix with :meth:`add`."""
        parts = self._parts
        parts.append((t, gyr, acc, mag, rejected))
        self._n_parts += len(t)
        while self._n_parts >= BLOCK:
            self._reduce_parts(BLOCK)

    def _reduce_parts(self, n: int) -> None:
        """Reduce the first ``n`` samples of the blocks given to :meth:`add_block`."""
        cols = [np.concatenate(c) for c in zip(*self._parts, strict=True)]
        self._parts = [tuple(c[n:] for c in cols)] if len(cols[0]) > n else []
        self._n_parts -= min(n, len(cols[0]))
        self._reduce(*(c[:n] for c in cols))

    def _reduce(self, t: np.ndarray, gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray, rejected: np.ndarray) -> None:
        self._timing(t)
        ok = np.isfinite(gyr).all(axis=1) & np.isfinite(acc).all(axis=1)
        gyr, acc = gyr[ok], acc[ok]
        if len(gyr):
            self._gyro_peak.add(gyr)
            self._acc_peak.add(acc)
            self._rest(gyr, acc)
            self._vibration(acc)
        self._magnetometer(mag, acc if ok.all() else np.where(ok[:, None], acc, np.nan), rejected)

    def _timing(self, t: np.ndarray) -> None:
        if not self.n:
            self.t_first = float(t[0])
        prev = np.concatenate(([self.t_last], t[:-1])) if self.n else t[:-1]
        cur = t if self.n else t[1:]
        dt = cur - prev
        self.n += len(t)
        self.t_last = float(t[-1])
        if not len(dt):
            return
        if not math.isfinite(self._dt_nominal):
            pos = dt[dt > 0]
            if len(pos):
                self._dt_nominal = float(np.median(pos))  # the first block's median interval: the nominal rate
        nom = self._dt_nominal
        self._n_not_increasing += int(np.count_nonzero(dt <= 0))
        if math.isfinite(nom):
            gaps = dt[dt > 1.5 * nom]
            self._n_gaps += len(gaps)
            if len(gaps):
                self._max_gap_s = max(self._max_gap_s, float(gaps.max()))
            regular = dt[(dt > 0.5 * nom) & (dt < 1.5 * nom)]
            self._jit += (len(regular), float(regular.sum()), float(np.square(regular).sum()))

    def _windows(self, x: np.ndarray, seconds: float) -> np.ndarray:
        """``x`` (N,3) as (windows, samples, 3); a partial last window is left out."""
        nom = self._dt_nominal if math.isfinite(self._dt_nominal) else 0.01
        w = max(4, round(seconds / nom))
        k = len(x) // w
        return x[:k * w].reshape(k, w, 3)

    def _rest(self, gyr: np.ndarray, acc: np.ndarray) -> None:
        wg, wa = self._windows(gyr, REST_WINDOW_S), self._windows(acc, REST_WINDOW_S)
        if not len(wg):
            return
        sg, sa, mg = wg.std(axis=1), wa.std(axis=1), wg.mean(axis=1)
        steady = (sg.max(axis=1) < REST_GYRO_STD_RAD_S) & (sa.max(axis=1) < REST_ACC_STD_M_S2)
        within = np.abs(mg).max(axis=1) < REST_BIAS_MAX_RAD_S
        rest = steady & within
        fast = steady & ~within
        if fast.any():
            self._steady_fast_n += int(np.count_nonzero(fast))
            self._steady_fast_gyr += mg[fast].sum(axis=0)
        if not rest.any():
            return
        means = mg[rest]
        self._rest_n += len(means)
        self._rest_gyr += means.sum(axis=0)
        self._rest_gyr_var += float(np.square(sg[rest]).mean(axis=1).sum())
        self._rest_acc_norm += float(np.linalg.norm(wa[rest], axis=2).mean(axis=1).sum())
        if self._rest_first is None:
            self._rest_first = means[0]
        self._rest_last = means[-1]

    def _vibration(self, acc: np.ndarray) -> None:
        w = self._windows(acc, VIBRATION_WINDOW_S)
        if not len(w):
            return
        hp2 = np.square(w - w.mean(axis=1, keepdims=True)).mean(axis=1)  # (windows, 3) mean square per axis
        self._vib_n += len(hp2)
        self._vib[:3] += hp2.sum(axis=0)
        self._vib_max = max(self._vib_max, float(np.sqrt(hp2.max())))

    def _magnetometer(self, mag: np.ndarray, acc: np.ndarray, rejected: np.ndarray) -> None:
        have = np.isfinite(mag).all(axis=1)
        if not have.any():
            return
        self._mag_rejected += int(np.count_nonzero(rejected & have))
        m = mag[have]
        self._mag_n += len(m)
        norm = np.linalg.norm(m, axis=1)
        self._mag[:3] += (len(norm), float(norm.sum()), float(np.square(norm).sum()))
        a = acc[have]
        an = np.linalg.norm(a, axis=1)
        level = np.isfinite(an) & (np.abs(an - G_M_S2) < 0.5) & (norm > 0)
        if level.any():
            sin_dip = np.einsum('ij,ij->i', a[level], m[level]) / (an[level] * norm[level])
            dip = np.arcsin(np.clip(sin_dip, -1.0, 1.0))
            self._dip += (len(dip), float(dip.sum()), float(np.square(dip).sum()))
        rows = np.hstack([m, np.ones((len(m), 1))])
        self._ata += rows.T @ rows
        self._aty += rows.T @ np.square(norm)
        u = m[norm > 0] / norm[norm > 0, None]
        self._dir += u.T @ u
        self._dir_sum += u.sum(axis=0)

    def result(self, filt: dict[str, Any] | None = None) -> dict[str, float]:
        """The metrics (name -> number, SI units in the names; NaN: not measurable in this bag). ``filt``: the
        filter's figures to include (see :func:`ccf_ros.fleet.task.filter_metrics`)."""
        self.flush()
        if self._n_parts:
            self._reduce_parts(self._n_parts)
        nan = math.nan
        out: dict[str, float] = {'samples': float(self.n)}
        nom = self._dt_nominal
        span = self.t_last - self.t_first if self.n > 1 else nan
        expected = span / nom + 1 if math.isfinite(nom) and nom > 0 else nan
        jn, js, jss = self._jit
        # Missing samples: those the span holds at the nominal rate beyond the ones received (a swapped or repeated
        # stamp leaves the span and the count as they are; a gap does not).
        dropped = max(0, round(expected - self.n)) if math.isfinite(expected) else 0
        out |= {
            'start_time_s': self.t_first,
            'duration_s': span,
            'rate_hz': 1.0 / nom if math.isfinite(nom) and nom > 0 else nan,
            'dropped_samples': float(dropped),
            'dropped_share': dropped / expected if expected and math.isfinite(expected) else nan,
            'gaps': float(self._n_gaps),
            'max_gap_s': self._max_gap_s,
            'not_increasing_stamps': float(self._n_not_increasing),
            'not_increasing_share': self._n_not_increasing / max(self.n - 1, 1),
            'jitter_s': math.sqrt(max(jss / jn - (js / jn) ** 2, 0.0)) if jn else nan,
            'gyro_peak_rad_s': float(self._gyro_peak.peak.max()),
            'gyro_clip_samples': float(self._gyro_peak.clipped(Thresholds.gyro_range_min_rad_s)),
            'acc_peak_m_s2': float(self._acc_peak.peak.max()),
            'acc_clip_samples': float(self._acc_peak.clipped(Thresholds.acc_range_min_m_s2)),
            'rest_s': self._rest_n * REST_WINDOW_S,
            'steady_beyond_clamp_s': self._steady_fast_n * REST_WINDOW_S,
            'steady_beyond_clamp_rad_s': (float(np.abs(self._steady_fast_gyr / self._steady_fast_n).max())
                                          if self._steady_fast_n else nan),
        }
        if self._rest_n * REST_WINDOW_S >= REST_MIN_S:
            bias = self._rest_gyr / self._rest_n
            change = (np.linalg.norm(self._rest_last - self._rest_first)
                      if self._rest_first is not None and self._rest_last is not None else nan)
            acc_norm = self._rest_acc_norm / self._rest_n
            out |= {
                'gyro_bias_x_rad_s': float(bias[0]), 'gyro_bias_y_rad_s': float(bias[1]),
                'gyro_bias_z_rad_s': float(bias[2]), 'gyro_bias_rad_s': float(np.linalg.norm(bias)),
                'gyro_bias_change_rad_s': float(change),
                'gyro_noise_rad_s': math.sqrt(self._rest_gyr_var / self._rest_n),
                'acc_norm_rest_m_s2': acc_norm,
                'acc_norm_error_share': abs(acc_norm - G_M_S2) / G_M_S2,
            }
        else:
            out |= dict.fromkeys(('gyro_bias_x_rad_s', 'gyro_bias_y_rad_s', 'gyro_bias_z_rad_s', 'gyro_bias_rad_s',
                                  'gyro_bias_change_rad_s', 'gyro_noise_rad_s', 'acc_norm_rest_m_s2',
                                  'acc_norm_error_share'), nan)
        if self._vib_n:
            axes = np.sqrt(self._vib[:3] / self._vib_n)
            out |= {'vibration_m_s2': float(axes.max()), 'vibration_x_m_s2': float(axes[0]),
                    'vibration_y_m_s2': float(axes[1]), 'vibration_z_m_s2': float(axes[2]),
                    'vibration_max_window_m_s2': self._vib_max}
        else:
            out |= dict.fromkeys(('vibration_m_s2', 'vibration_x_m_s2', 'vibration_y_m_s2', 'vibration_z_m_s2',
                                  'vibration_max_window_m_s2'), nan)
        out |= self._mag_result()
        if filt:
            out |= filt
        return out

    def _mag_result(self) -> dict[str, float]:
        nan = math.nan
        out = dict.fromkeys(('mag_norm_mean', 'mag_norm_std', 'mag_norm_cv', 'mag_dip_mean_rad', 'mag_dip_std_rad',
                             'mag_rejected_share', 'hard_iron_x', 'hard_iron_y', 'hard_iron_z', 'mag_coverage'), nan)
        n, s, ss = self._mag[:3]
        if not n:
            return out
        out['mag_norm_mean'] = s / n
        out['mag_norm_std'] = math.sqrt(max(ss / n - (s / n) ** 2, 0.0))
        out['mag_norm_cv'] = out['mag_norm_std'] / out['mag_norm_mean'] if out['mag_norm_mean'] > 0 else nan
        out['mag_rejected_share'] = self._mag_rejected / self._mag_n
        dn, ds, dss = self._dip
        if dn:
            out['mag_dip_mean_rad'] = ds / dn
            out['mag_dip_std_rad'] = math.sqrt(max(dss / dn - (ds / dn) ** 2, 0.0))
        mean_dir = self._dir_sum / n
        cov = self._dir / n - np.outer(mean_dir, mean_dir)
        coverage = float(np.linalg.eigvalsh(cov)[0])  # 1/3 for every direction alike, 0 for rotations about one axis
        out['mag_coverage'] = coverage
        if coverage > COVERAGE_MIN:
            try:
                sol = np.linalg.solve(self._ata, self._aty)
            except np.linalg.LinAlgError:
                return out
            out['hard_iron_x'], out['hard_iron_y'], out['hard_iron_z'] = (float(v) for v in sol[:3] / 2.0)
        return out


#: Least spread of field directions (smallest eigenvalue of their covariance; 1/3 for a full sphere) for a hard-iron
#: estimate: below it the sphere fit is ill-conditioned (rotations about one axis only).
COVERAGE_MIN = 0.05

#: metric -> (flag, thresholds attribute)
_RULES = (
    ('dropped_share', 'samples_dropped', 'dropped_share'),
    ('not_increasing_share', 'stamps_not_increasing', 'not_increasing_share'),
    ('gyro_clip_samples', 'gyro_clipping', 'clip_samples'),
    ('acc_clip_samples', 'acc_clipping', 'clip_samples'),
    ('gyro_bias_rad_s', 'gyro_bias_high', 'gyro_bias_rad_s'),
    ('gyro_bias_change_rad_s', 'gyro_bias_unstable', 'gyro_bias_change_rad_s'),
    ('acc_norm_error_share', 'acc_norm_off', 'acc_norm_error_share'),
    ('vibration_m_s2', 'vibration_high', 'vibration_m_s2'),
    ('mag_norm_cv', 'mag_disturbed', 'mag_norm_cv'),
    ('filter_gyro_only_share', 'gyro_only_high', 'gyro_only_share'),
)


def judge(metrics: dict[str, float], th: Thresholds | None = None) -> tuple[str, list[str]]:
    """``(health, flags)`` of a bag's metrics: ``ok``/``warn``/``fail`` and the raised flags (vocabulary order)."""
    th = th or Thresholds()
    level: dict[str, int] = {}
    for metric, flag, attr in _RULES:
        v = metrics.get(metric, math.nan)
        if v is None or not math.isfinite(v):
            continue
        warn, fail = getattr(th, attr)
        if v > warn:
            level[flag] = 2 if v > fail else 1
    if (metrics.get('rest_s', 0.0) < REST_MIN_S and metrics.get('steady_beyond_clamp_s', 0.0) >= REST_MIN_S
            and metrics.get('steady_beyond_clamp_rad_s', 0.0) > REST_BIAS_MAX_RAD_S):
        # No rest to measure the offset at, and the gyro reads a steady rate the filter's clamp cannot hold.
        level['gyro_bias_high'] = 2
    if metrics.get('filter_nonfinite_resets', 0) > 0:
        level['filter_nonfinite'] = 2
    if metrics.get('filter_restarts', 0) > 0:
        level['filter_restarts'] = 1
    flags = [f for f in FLAGS if f in level]
    worst = max(level.values(), default=0)
    return ('ok', 'warn', 'fail')[worst], flags
