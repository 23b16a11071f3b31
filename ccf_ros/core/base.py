"""Shared sample handling for every orientation filter of the core.

A filter sees one IMU sample at a time through :meth:`OrientationFilter.update`. The rules for bad input live here,
once, so that every filter (the CCF and the baselines) answers the same samples:

* non-finite gyroscope, or faster than :data:`GYRO_MAX_RAD_S` (a corrupted message) -> the sample is skipped: no
  state change, no output;
* stamp not later than the last accepted one (or non-finite) -> skipped;
* non-finite or zero accelerometer, or beyond :data:`ACC_MAX_M_S2` -> gyro-only propagation;
* non-finite or zero magnetometer (or none) -> no heading correction;
* gap longer than ``max_dt_s`` -> re-initialise from accelerometer/magnetometer instead of integrating across it;
* before the first sample with a valid accelerometer there is no orientation: those samples are skipped.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, fields
from enum import IntEnum
from typing import NamedTuple

from .fields import param as param  # re-exported: the params dataclasses define their fields with it
from .quaternion import WORLD_FRAMES, Quat, quat_mul_scalar, rpy_of


class Status(IntEnum):
    """Outcome of one :meth:`OrientationFilter.update`. Values below ``SKIPPED_BAD_GYRO`` produced an output."""

    UPDATED = 0
    INITIALIZED = 1
    REINITIALIZED_AFTER_GAP = 2
    SKIPPED_BAD_GYRO = 3
    SKIPPED_STAMP = 4
    SKIPPED_NO_ACC_YET = 5


#: ``status < ANSWERED_BELOW`` means the sample advanced the filter.
ANSWERED_BELOW = int(Status.SKIPPED_BAD_GYRO)
# Plain ints of the statuses for the per-sample path (an IntEnum member costs an attribute lookup there).
_UPDATED = int(Status.UPDATED)
_INITIALIZED = int(Status.INITIALIZED)
_REINITIALIZED = int(Status.REINITIALIZED_AFTER_GAP)
_BAD_GYRO = int(Status.SKIPPED_BAD_GYRO)
_BAD_STAMP = int(Status.SKIPPED_STAMP)
_NO_ACC_YET = int(Status.SKIPPED_NO_ACC_YET)
_INF = math.inf
#: A gyro reading above this norm, rad/s, is not a rotation but a corrupted message (1000 rad/s = 57 000 °/s, 25x the
#: range of any MEMS gyro; a finite 1e200 would otherwise overflow the integration to inf).
GYRO_MAX_RAD_S = 1000.0
#: An accelerometer reading above this norm, m/s², is a corrupted message (about 1000 g, 2.5x a high-g MEMS range).
ACC_MAX_M_S2 = 1.0e4
_GYRO_MAX2 = GYRO_MAX_RAD_S * GYRO_MAX_RAD_S
_ACC_MAX2 = ACC_MAX_M_S2 * ACC_MAX_M_S2
#: Squared norms below these are zero vectors: no direction (accelerometer m²/s⁴; magnetometer in any unit²).
_ACC_MIN2 = 1e-12
_MAG_MIN2 = 1e-30


def acc_usable(acc: Sequence[float]) -> bool:
    """Whether :meth:`OrientationFilter.update` uses this accelerometer sample (m/s², 3 values): finite, not zero,
    not beyond :data:`ACC_MAX_M_S2`. (``update`` applies the same rule inline.)"""
    return _ACC_MIN2 < acc[0] * acc[0] + acc[1] * acc[1] + acc[2] * acc[2] < _ACC_MAX2


def mag_usable(mag: Sequence[float]) -> bool:
    """Whether :meth:`OrientationFilter.update` can use this magnetometer sample (any unit, 3 values): finite and
    not zero. (``update`` applies the same rule inline.)"""
    return _MAG_MIN2 < mag[0] * mag[0] + mag[1] * mag[1] + mag[2] * mag[2] < _INF


class FilterFlags(NamedTuple):
    """What the filter knows about its own state after the latest sample (read-only; see :attr:`~OrientationFilter.flags`).

    Attributes:
        initialized: an orientation exists (False until the first sample with a usable accelerometer).
        at_rest: the IMU is detected at rest (the gyro bias is then learnt from the gyro directly).
        acc_used: the latest accelerometer sample was usable; False: gyro-only propagation.
        mag_used: the latest magnetometer sample corrected the heading.
        mag_disturbed: the magnetometer disagrees with its reference field; heading runs on the gyro.
        heading_absolute: heading is referenced to magnetic north (False: 6-D, heading relative to the start).
    """

    initialized: bool
    at_rest: bool
    acc_used: bool
    mag_used: bool
    mag_disturbed: bool
    heading_absolute: bool


def check_positive(name: str, value: float) -> None:
    """Raise ``ValueError`` naming ``name`` unless ``value`` is a finite number > 0."""
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value) or value <= 0:
        raise ValueError(f'{name} must be a finite number > 0, got {value!r}')


def check_range(name: str, value: float, lo: float, hi: float) -> None:
    """Raise ``ValueError`` unless ``lo <= value <= hi``."""
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not (lo <= value <= hi):
        raise ValueError(f'{name} must be in [{lo}, {hi}], got {value!r}')


def per_axis(name: str, value: float | Sequence[float], lo: float, hi: float) -> tuple[float, float, float]:
    """``(roll, pitch, yaw)`` floats from one number or three, each in ``[lo, hi]``; ``ValueError`` naming ``name``."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        vals: tuple[float, ...] = (float(value),) * 3
    else:
        vals = floats(name, value, 3, lo, hi, what='a number or 3 numbers (roll, pitch, yaw)')
    for v in vals:
        check_range(name, v, lo, hi)
    return (vals[0], vals[1], vals[2])


def floats(name: str, value: object, n: int, lo: float, hi: float, *, what: str = '') -> tuple[float, ...]:
    """``n`` floats from a sequence, each in ``[lo, hi]``; ``ValueError`` naming ``name`` and the value."""
    what = what or f'{n} numbers'
    try:
        vals = tuple(float(v) for v in value)  # type: ignore[attr-defined]
    except (TypeError, ValueError):
        raise ValueError(f'{name} must be {what}, got {value!r}') from None
    if len(vals) != n or any(isinstance(v, bool) for v in value):  # type: ignore[attr-defined]
        raise ValueError(f'{name} must be {what}, got {value!r}')
    for v in vals:
        check_range(name, v, lo, hi)
    return vals


def check_params(params: object) -> None:
    """Check every :func:`~ccf_ros.core.fields.param` field of a params dataclass against its definition (type,
    range, choices, length); ``ValueError`` naming the field and its value."""
    for f in fields(params):  # type: ignore[arg-type]
        if 'unit' not in f.metadata:
            continue
        m, name, value = f.metadata, f.name, getattr(params, f.name)
        lo, hi = m['range'] or (-math.inf, math.inf)
        if isinstance(f.default, bool):
            if not isinstance(value, bool):
                raise ValueError(f'{name} must be a bool, got {value!r}')
        elif m['per_axis']:
            per_axis(name, value, lo, hi)
        elif isinstance(f.default, tuple):
            n = len(value) if isinstance(value, tuple) and len(value) in m['lengths'] else m['lengths'][0]
            floats(name, value, n, lo, hi, what=m['what'])
        elif isinstance(f.default, str):
            if m['choices'] and value not in m['choices']:
                raise ValueError(f'{name} must be one of {list(m["choices"])}, got {value!r}')
            if not isinstance(value, str):
                raise ValueError(f'{name} must be a string, got {value!r}')
        else:
            if m['above']:
                check_positive(name, value)
            check_range(name, value, lo, hi)


@dataclass(frozen=True)
class CommonParams:
    """Parameters every filter shares (each field's description is its documentation; see :func:`param`)."""

    max_dt_s: float = param(0.5, 's', 'gap longer than this (s) re-initialises from accelerometer/magnetometer '
                            'instead of integrating', 0.0, 1e9, above=True)
    use_mag: bool = param(True, '-', 'use the magnetometer for heading (false: 6-D, heading drifts)')
    world_frame: str = param('enu', '-', 'world frame of the output orientation: enu (REP-103), ned or nwu',
                             choices=tuple(sorted(WORLD_FRAMES)))

    def __post_init__(self) -> None:
        check_params(self)


class OrientationFilter(ABC):
    """One IMU sample in, one orientation out. Subclasses implement :meth:`_init` and :meth:`_step`.

    Internally every filter works in ENU; :attr:`quaternion` converts to ``params.world_frame``.
    """

    #: registry name, e.g. ``ccf``
    name = ''
    # Slots: attribute access on the per-sample path is measurably faster than through __dict__.
    __slots__ = (
        '_counts',
        '_frame',
        '_identity_frame',
        '_max_dt',
        '_n_updated',
        '_q',
        '_t_last',
        '_t_no_acc',
        '_t_no_mag',
        '_use_mag',
        'at_rest',
        'initialized',
        'mag_disturbed',
        'n_no_acc',
        'n_no_mag',
        'n_nonfinite_resets',
        'params',
        'still_hint',
    )
    params: CommonParams

    def __init__(self, params: CommonParams) -> None:
        #: an outside motion hint (odometry, cmd_vel): True still, False moving, None none; filters that learn
        #: the gyro bias at rest learn it only when this is not False. Kept by reset() (it is an input).
        self.still_hint: bool | None = None
        self._apply_params(params)
        self.reset()

    def _apply_params(self, params: CommonParams) -> None:
        self.params = params
        self._frame = WORLD_FRAMES[params.world_frame]
        self._identity_frame = params.world_frame == 'enu'
        # Cached for the per-sample path (attribute chains cost as much as arithmetic in CPython).
        self._use_mag = params.use_mag
        self._max_dt = params.max_dt_s

    def set_params(self, params: CommonParams) -> None:
        """Switch to new parameters of the same filter *without* resetting the estimate (live gain changes)."""
        if type(params) is not type(self.params):
            raise ValueError(f'{type(self).__name__} takes {type(self.params).__name__}, got {type(params).__name__}')
        self._apply_params(params)
        self._params_changed()

    def _params_changed(self) -> None:
        """Re-derive coefficients after :meth:`set_params`; state is kept."""
        return

    def reset(self) -> None:
        """Forget everything learnt: equivalent to a fresh instance with the same parameters."""
        self._t_last = -math.inf
        self.initialized = False
        # Internal body->ENU orientation [w, x, y, z].
        self._q: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
        # Per-status sample counts (see :attr:`counts`); the common one, UPDATED, in its own int: cheaper.
        self._counts = [0] * len(Status)
        self._n_updated = 0
        self.n_no_acc = 0
        self.n_no_mag = 0
        #: times the state became non-finite (a bug or absurd input) and the filter re-initialised instead
        self.n_nonfinite_resets = 0
        # Stamps of the latest samples without a usable accelerometer / magnetometer (flags at no per-sample cost).
        self._t_no_acc = -math.inf
        self._t_no_mag = -math.inf
        #: set by filters that detect rest / magnetic disturbances (see :class:`FilterFlags`)
        self.at_rest = False
        self.mag_disturbed = False
        self._reset_state()

    @abstractmethod
    def _reset_state(self) -> None:
        """Reset filter-specific state."""

    @abstractmethod
    def _init(self, ax: float, ay: float, az: float, mx: float, my: float, mz: float, mag_ok: bool) -> None:
        """Set the orientation from a valid accelerometer (and magnetometer if ``mag_ok``)."""

    @abstractmethod
    def _step(
        self, dt: float, gx: float, gy: float, gz: float, ax: float, ay: float, az: float, acc_n2: float,
        mx: float, my: float, mz: float, mag_n2: float,
    ) -> None:
        """Advance by ``dt`` s. ``acc_n2``/``mag_n2`` are the squared norms, 0.0 when that sensor is unusable."""

    def update(
        self,
        t_s: float,
        gyr: Sequence[float],
        acc: Sequence[float],
        mag: Sequence[float] | None = None,
    ) -> int:
        """Process one sample.

        Args:
            t_s: sample time, s (header stamp).
            gyr: angular rate, rad/s, body frame, 3 values.
            acc: specific force, m/s², body frame (+g up at rest, REP-145), 3 values.
            mag: magnetic field, any unit (tesla in ROS), body frame, or ``None``.

        Returns:
            a :class:`Status` value (as ``int``); below :data:`ANSWERED_BELOW` the orientation is valid.
        """
        gx, gy, gz = gyr
        ax, ay, az = acc
        return self._update_floats(t_s, gx, gy, gz, ax, ay, az, mag)

    def _update_floats(
        self, t_s: float, gx: float, gy: float, gz: float, ax: float, ay: float, az: float,
        mag: Sequence[float] | None,
    ) -> int:
        """:meth:`update` on the gyro's and accelerometer's components as floats (the engine's per-sample paths call
        it directly: no tuple built and unpacked per sample). The accelerometer is unpacked before the gyro is
        checked, so a malformed ``acc`` (not 3 values) raises even for a sample with a bad gyro."""
        # Comparisons with NaN are False: one test catches NaN, Inf and a corrupted huge value in any component.
        if not gx * gx + gy * gy + gz * gz < _GYRO_MAX2:
            self._counts[_BAD_GYRO] += 1
            return _BAD_GYRO
        dt = t_s - self._t_last
        # Comparisons with NaN are False: this rejects dt <= 0 and (t - t is 0.0 only if finite) a NaN or infinite
        # stamp (the first dt is inf).
        if not (dt > 0.0 and t_s - t_s == 0.0):
            self._counts[_BAD_STAMP] += 1
            return _BAD_STAMP
        self._t_last = t_s
        # The accelerometer's and the magnetometer's checks below are written out, not one helper: a call costs
        # ~50-100 ns per sample on this path (a hot-path repeat on purpose).
        acc_n2 = ax * ax + ay * ay + az * az
        if not _ACC_MIN2 < acc_n2 < _ACC_MAX2:
            acc_n2 = 0.0
            self.n_no_acc += 1
            self._t_no_acc = t_s
        if mag is not None and self._use_mag:
            mx, my, mz = mag
            mag_n2 = mx * mx + my * my + mz * mz
            if not _MAG_MIN2 < mag_n2 < _INF:
                mag_n2 = 0.0
                self.n_no_mag += 1
                self._t_no_mag = t_s
        else:
            mx = my = mz = mag_n2 = 0.0
            self._t_no_mag = t_s
        if dt <= self._max_dt and self.initialized:
            self._step(dt, gx, gy, gz, ax, ay, az, acc_n2, mx, my, mz, mag_n2)
            w = self._q[0]
            if w - w == 0.0:
                self._n_updated += 1
                return _UPDATED
            # Non-finite state (should never happen): start over from this sample rather than publish NaN.
            self.n_nonfinite_resets += 1
            self.initialized = False
            self._q = (1.0, 0.0, 0.0, 0.0)
            self._reset_state()
            status = _REINITIALIZED
        else:
            status = _REINITIALIZED if self.initialized else _INITIALIZED
        if acc_n2 == 0.0:
            if self.initialized:
                # After a gap without a usable accelerometer: hold, do not integrate across the gap.
                self._n_updated += 1
                return _UPDATED
            self._counts[_NO_ACC_YET] += 1
            return _NO_ACC_YET
        self._init(ax, ay, az, mx, my, mz, mag_n2 != 0.0)
        self.initialized = True
        self._counts[status] += 1
        return status

    @property
    def counts(self) -> list[int]:
        """Samples processed so far per :class:`Status` (indexed by its value), since the last :meth:`reset`; a new
        list on every read (read-only)."""
        c = list(self._counts)
        c[_UPDATED] += self._n_updated
        return c

    @property
    def quaternion(self) -> tuple[float, float, float, float]:
        """Body->world orientation ``(w, x, y, z)`` in ``params.world_frame``."""
        if self._identity_frame:
            return self._q
        return quat_mul_scalar(self._frame, self._q)

    def estimate(self) -> tuple[Quat, tuple[float, float, float], tuple[float, float, float]]:
        """:attr:`quaternion`, :attr:`orientation_variance` and :attr:`gyro_bias` in one call: what the engine reads
        after every sample (one call instead of three)."""
        return self.quaternion, self.orientation_variance, self.gyro_bias

    @property
    def flags(self) -> FilterFlags:
        """Read-only state flags after the latest sample (see :class:`FilterFlags`)."""
        return FilterFlags(
            initialized=self.initialized,
            at_rest=self.at_rest,
            acc_used=self.initialized and self._t_no_acc != self._t_last,
            mag_used=self.initialized and self._t_no_mag != self._t_last and not self.mag_disturbed,
            mag_disturbed=self.mag_disturbed,
            heading_absolute=self._use_mag and self._heading_absolute(),
        )

    def _heading_absolute(self) -> bool:
        """Whether the heading has been referenced to magnetic north since the last (re)initialisation."""
        return self._t_no_mag != self._t_last

    @property
    @abstractmethod
    def gyro_bias(self) -> tuple[float, float, float]:
        """Gyroscope bias estimate, rad/s, body frame (zero for filters that do not estimate it)."""

    @property
    @abstractmethod
    def orientation_variance(self) -> tuple[float, float, float]:
        """Variance of roll, pitch and yaw errors, rad², for ``orientation_covariance``'s diagonal."""

    def set_gyro_bias(self, bias_rad_s: tuple[float, float, float], sigma_rad_s: float) -> bool:
        """Start from a known gyro bias (rad/s, body frame) with 1-σ uncertainty ``sigma_rad_s`` (rad/s), e.g. one
        saved by an earlier run; the orientation is kept. Returns False if this filter estimates no bias (ignored)."""
        return False

    def magnetometer_changed(self, change_rel: float | None = None) -> None:  # noqa: B027 (a hook with a default)
        """The magnetometer's calibration changed under the filter (an online hard-iron offset was applied or moved;
        ``change_rel``: how far off the samples before it may have been, over the field norm; None if not known): a
        filter that learns a reference of the field (norm, dip) can take the new one. No-op by default."""

    def set_heading(self, yaw_rad: float) -> None:
        """Turn the estimate about the world's vertical so that its yaw (Z-Y-X, in ``params.world_frame``) is
        ``yaw_rad`` (rad); roll, pitch, bias and the rest are kept. Nothing before initialisation."""
        if not self.initialized:
            return
        d = math.remainder(yaw_rad - rpy_of(self.quaternion)[2], 2.0 * math.pi)
        # The internal frame is ENU (z up); NED's yaw is about z down.
        self._rotate_about_up(-d if self.params.world_frame == 'ned' else d)

    def _rotate_about_up(self, angle_rad: float) -> None:
        """Rotate the state about the internal ENU frame's z by ``angle_rad``; filters keeping more world-frame
        state (or their own orientation form) extend this."""
        c, s = math.cos(0.5 * angle_rad), math.sin(0.5 * angle_rad)
        self._q = quat_mul_scalar((c, 0.0, 0.0, s), self._q)
