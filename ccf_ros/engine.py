"""The per-message path shared by ``ccf_node`` and ``ccf replay``: pair magnetometer, run the core, shape output.

No ROS import: the adapters convert messages to floats, call :meth:`ImuEngine.on_imu`/:meth:`ImuEngine.on_mag`
in arrival order, and convert the :class:`Output` back. Same input in the same order -> same output, bit for bit.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from .core.base import ANSWERED_BELOW, OrientationFilter, Status
from .core.pairing import MagPairer
from .core.quaternion import to_xyzw
from .settings import AdapterSettings

#: A stamp this much (s) before the latest one is a clock jump, not a late sample: the filter restarts.
JUMP_BACK_RESET_S = 1.0
#: ... and this many such samples in a row (one stray stamp is just skipped).
JUMP_BACK_SAMPLES = 3


class Output(NamedTuple):
    """One answered IMU sample.

    Attributes:
        orientation_xyzw: body->world orientation in message order.
        covariance: row-major 3x3 orientation covariance (rad²), 9 values.
        bias: gyro-bias estimate, rad/s, body frame.
        status: the core's :class:`~ccf_ros.core.base.Status`.
    """

    orientation_xyzw: tuple[float, float, float, float]
    covariance: tuple[float, ...]
    bias: tuple[float, float, float]
    status: int


class ImuEngine:
    """Magnetometer pairing + filter + covariance for a stream of IMU/magnetometer messages."""

    def __init__(self, filt: OrientationFilter, settings: AdapterSettings | None = None) -> None:
        self.filter = filt
        self.settings = settings or AdapterSettings()
        self.pairer = MagPairer(timeout_s=self.settings.mag_timeout_s)
        self.n_in = 0
        self.n_resets_jump = 0
        self._t_const = 0.0
        self._t_last = -math.inf
        self._n_far_back = 0
        self._counts_before = [0] * len(filt.counts)
        self._no_acc_before = 0
        self._no_mag_before = 0
        self.set_settings(self.settings)

    def set_settings(self, settings: AdapterSettings) -> None:
        """Apply new adapter settings; the filter state is kept."""
        self.settings = settings
        self.pairer.timeout_s = settings.mag_timeout_s
        self._constant_dt = settings.constant_dt
        self._stddev = settings.orientation_stddev

    def reset(self) -> None:
        """Fresh filter state and no magnetometer history (parameters kept); counters keep counting."""
        f = self.filter
        self._counts_before = [a + b for a, b in zip(self._counts_before, f.counts, strict=True)]
        self._no_acc_before += f.n_no_acc
        self._no_mag_before += f.n_no_mag
        self._n_far_back = 0
        f.reset()
        self.pairer.reset()
        self._t_const = 0.0
        self._t_last = -math.inf

    def on_mag(self, t_s: float, field: tuple[float, float, float]) -> None:
        """A magnetometer message: stamp (s), field (any unit, body frame)."""
        self.pairer.add(t_s, field)

    def on_imu(
        self, t_s: float, gyr: tuple[float, float, float], acc: tuple[float, float, float]
    ) -> Output | None:
        """An IMU message: stamp (s), rate (rad/s), specific force (m/s²). None if the sample was skipped."""
        self.n_in += 1
        if t_s < self._t_last - JUMP_BACK_RESET_S:
            # Far behind: a stray stamp is skipped by the filter; several in a row mean the clock jumped back (bag
            # loop, simulation reset), and the filter starts over instead of waiting for time to catch up.
            self._n_far_back += 1
            if self._n_far_back >= JUMP_BACK_SAMPLES:
                self.reset()
                self.n_resets_jump += 1
        else:
            self._n_far_back = 0
            if t_s > self._t_last:
                self._t_last = t_s
        mag = self.pairer.get(t_s)
        if self._constant_dt > 0.0:
            # Fixed sample period: a synthetic clock advanced per message replaces the header stamps.
            self._t_const += self._constant_dt
            t_s = self._t_const
        f = self.filter
        status = f.update(t_s, gyr, acc, mag)
        if status >= ANSWERED_BELOW:
            return None
        sd = self._stddev
        vr, vp, vy = (sd * sd,) * 3 if sd > 0.0 else f.orientation_variance
        return Output(to_xyzw(f.quaternion), (vr, 0.0, 0.0, 0.0, vp, 0.0, 0.0, 0.0, vy), f.gyro_bias, status)

    def counts(self) -> list[int]:
        """Samples per :class:`~ccf_ros.core.base.Status` since this engine was made."""
        return [a + b for a, b in zip(self._counts_before, self.filter.counts, strict=True)]

    def skipped_by_reason(self) -> dict[str, int]:
        """Counts of skipped samples by reason name (only non-zero ones)."""
        c = self.counts()
        return {Status(i).name.lower(): c[i] for i in range(ANSWERED_BELOW, len(c)) if c[i]}

    def answered(self) -> int:
        """Number of samples that produced an output."""
        return sum(self.counts()[:ANSWERED_BELOW])

    @property
    def n_no_acc(self) -> int:
        """Samples propagated gyro-only (unusable accelerometer)."""
        return self._no_acc_before + self.filter.n_no_acc

    @property
    def n_no_mag(self) -> int:
        """Samples without heading correction (unusable magnetometer)."""
        return self._no_mag_before + self.filter.n_no_mag
