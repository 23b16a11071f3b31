"""The per-message path shared by ``ccf_node`` and ``ccf replay``: pair magnetometer, run the core, shape output.

No ROS import: the adapters convert messages to floats, call :meth:`ImuEngine.on_imu`/:meth:`ImuEngine.on_mag`
in arrival order, and convert the :class:`Output` back. Same input in the same order -> same output, bit for bit.

Every IMU message is answered once an orientation exists, like imu_tools does: a sample that cannot advance the
filter (repeated or backward stamp, non-finite or corrupted gyro) gets the current orientation, and is counted.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

from .core.base import ANSWERED_BELOW, OrientationFilter, Status, acc_usable, mag_usable
from .core.ccf import GRAVITY_M_S2, CcfParams, QuaternionCcf
from .core.hard_iron import UPDATE_PERIOD_S, HardIronEstimator, HardIronStatus
from .core.pairing import MagPairer
from .core.quaternion import (
    WORLD_FRAMES,
    level_quat,
    quat_from_acc_mag_scalar,
    quat_mul_scalar,
    relevel,
    rpy_of,
)
from .frames import IDENTITY, Mat3, apply, is_identity, matmul, transpose
from .settings import EngineSettings
from .state_file import State, StateFileError, read_state, write_state

#: A stamp this much (s) before the latest one is a clock jump, not a late sample: the filter restarts.
JUMP_BACK_RESET_S = 1.0
#: ... and this many such samples in a row (one stray stamp is just skipped).
JUMP_BACK_SAMPLES = 3
#: Gain of the running share of answers with a held orientation (:attr:`ImuEngine.stale_share`): about
#: the latest 1/this samples.
STALE_SHARE_GAIN = 0.01
#: A stamp this much (s) after the latest one, and beyond the filter's ``max_dt_s``, is a new timeline (a gap) only
#: once the next sample continues from it; a lone one (a clock-sync step undone, a bad stamp) is skipped instead of
#: re-initialising the filter and leaving every later sample "far behind".
JUMP_AHEAD_S = 1.0
#: A state file (``bias_file``) older than this (s) is not used: the sensor may have changed since.
STATE_MAX_AGE_S = 30 * 86400.0
#: A heading set in 9-D before the magnetometer gave north is carried by the gyro this long (s) after it does, while
#: the filter acquires north, for filters without ``tau_mag_s`` (see :meth:`ImuEngine.set_heading`).
ANCHOR_S = 15.0
_UPDATED_STATUS = int(Status.UPDATED)

Vec3 = tuple[float, float, float]
#: Three columns (x, y, z) of N floats each.
Columns = tuple[Sequence[float], Sequence[float], Sequence[float]]


class Output(NamedTuple):
    """One answered IMU sample.

    Attributes:
        orientation_xyzw: body->world orientation in message order (turned by ``yaw_offset - declination``).
        covariance: row-major 3x3 orientation covariance (rad²), 9 values.
        bias: gyro-bias estimate, rad/s, body frame.
        status: the core's :class:`~ccf_ros.core.base.Status` (a ``SKIPPED_*`` value: the sample could not advance
            the filter and is answered with the current orientation).
        angular_velocity: rad/s to publish instead of the input's (bias subtracted), or None to keep the input's.
        linear_acceleration: m/s² to publish instead of the input's (gravity removed), or None to keep the input's.
    """

    orientation_xyzw: tuple[float, float, float, float]
    covariance: tuple[float, ...]
    bias: Vec3
    status: int
    angular_velocity: Vec3 | None = None
    linear_acceleration: Vec3 | None = None


_new_output = tuple.__new__
_NAN3 = (math.nan, math.nan, math.nan)


@dataclass
class ChunkAnswers:
    """The answers of :meth:`ImuEngine.on_chunk`, as columns over the answered IMU samples (M of them).

    Attributes:
        answered: (M,) which IMU samples of the chunk were answered (their index among its IMU samples).
        quaternion: (4 M,) flat: body->world orientation [w, x, y, z] per answer, turned as
            :attr:`Output.orientation_xyzw` is.
        variance: (3 M,) flat: roll, pitch, yaw variance, rad² (the covariance's diagonal; the rest is 0).
        bias: (3 M,) flat: gyro-bias estimate, rad/s.
        rate: (M,) :attr:`Output.angular_velocity`, or None (the input's is kept).
        linear_acceleration: (M,) :attr:`Output.linear_acceleration`, or None (the input's is kept).
        paired_mag: with ``observe``: (3 N,) flat: per IMU sample (answered or not) the paired magnetometer sample
            (NaN: none).
        mag_rejected: with ``observe``: per IMU sample whether the filter's disturbance gate rejected the field.
    """

    answered: list[int]
    quaternion: list[float]
    variance: list[float]
    bias: list[float]
    rate: list[Vec3] | None
    linear_acceleration: list[Vec3] | None
    paired_mag: list[float] | None
    mag_rejected: list[bool] | None


class _HeadingAnchor:
    """A heading set in 9-D before the magnetometer gave north (:meth:`ImuEngine.set_heading`): from the first
    north-referenced sample on, the gyro carries the set heading (``yaw``, rad, the filter's world frame) for
    ``settle_s`` while the filter acquires north, and the output offset is their difference."""

    __slots__ = ('base', 'q', 'settle_s', 't', 'until', 'yaw')

    def __init__(self, base: float, settle_s: float, q: tuple[float, float, float, float], t_s: float) -> None:
        #: the output offset when the heading was set, rad
        self.base = base
        self.settle_s = settle_s
        #: the filter's orientation (world frame, [w, x, y, z]) after the latest sample before north, and its time, s
        self.q = q
        self.t = t_s
        #: the set heading carried by the gyro, rad (None: north not given yet)
        self.yaw: float | None = None
        #: the anchor ends at this time, s (the offset stays)
        self.until = math.inf


class ImuEngine:
    """Magnetometer calibration and pairing + filter + output shaping for a stream of IMU/magnetometer messages."""

    def __init__(self, filt: OrientationFilter, settings: EngineSettings | None = None) -> None:
        self.filter = filt
        self.settings = settings or EngineSettings()
        self.pairer = MagPairer(timeout_s=self.settings.mag_timeout_s)
        self.n_in = 0
        #: outputs produced (every IMU sample once an orientation exists)
        self.n_out = 0
        self.n_resets_jump = 0
        #: samples answered with the current orientation although they could not advance the filter
        self.n_answered_stale = 0
        #: share of the latest ~100 answers given with a held orientation (running mean; 0 at the start)
        self.stale_share = 0.0
        self._t_const = 0.0
        #: latest IMU stamp processed on the current timeline, s (-inf if none since the start or a reset; not to be set
        #: by the caller: an attribute, as the node reads it per magnetometer message): stamps far behind it do not
        #: count until the timeline restarts on them (then the restarting stamp is the latest), nor does a lone stamp
        #: far ahead of it. The pairer has handed out every magnetometer sample up to it (+ its tolerance).
        self.latest_stamp_s = -math.inf
        #: the time the latest IMU sample was given to the filter at, s: its stamp, or the constant_dt clock
        self.clock_s = -math.inf
        #: the (calibrated) magnetometer sample paired with the latest IMU sample (None: none)
        self.paired_mag: Vec3 | None = None
        self._n_far_back = 0
        #: stamp of a lone sample far ahead of latest_stamp_s, waiting for the next one to confirm it (None: none)
        self._t_ahead: float | None = None
        self._counts_before = [0] * len(filt.counts)
        self._no_acc_before = 0
        self._no_mag_before = 0
        self._nonfinite_before = 0
        self._clipped_before = 0
        self._stateless_q: tuple[float, float, float, float] | None = None
        #: the held stateless orientation's heading came from a magnetometer sample
        self._stateless_heading = False
        #: the IMU messages' frame_id, once an adapter told it (:meth:`set_sensor_frame`); None: not yet
        self.sensor_frame_id: str | None = None
        #: a state file read by :meth:`load_state`, applied when the sensor's frame_id is known
        self._pending_state: State | None = None
        #: warnings about the state file, in order (also passed to :attr:`on_warning` if set)
        self.warnings: list[str] = []
        self.on_warning: Callable[[str], None] | None = None
        #: online hard-iron estimator (mag_online_calibration; None: off)
        self.hard_iron: HardIronEstimator | None = None
        #: yaw added to the output by set_heading in 9-D (rad; the magnetometer holds the filter to north)
        self.heading_offset_rad = 0.0
        #: a heading to give the filter once it initialises without a magnetometer heading (restore_heading)
        self._pending_heading: float | None = None
        #: a heading set (set_heading) before the filter initialised: applied as set_heading once it does
        self.pending_pose: float | None = None
        #: a heading set in 9-D before the magnetometer gave north (None: none; see _HeadingAnchor)
        self._anchor: _HeadingAnchor | None = None
        #: the motion hint expires at this stamp (s; inf: no hint in force)
        self._hint_until = math.inf
        #: the filter whose gyro range the engine checks on the raw readings (:meth:`_sync_raw_clip`; None: none)
        self._clip_filter: QuaternionCcf | None = None
        self.set_settings(self.settings)
        if self.settings.bias_file:
            self.load_state(self.settings.bias_file)

    def set_settings(self, settings: EngineSettings) -> None:
        """Apply new adapter settings; the filter state is kept."""
        self.settings = settings
        self.pairer.timeout_s = settings.mag_timeout_s
        self._constant_dt = settings.constant_dt
        self._stddev = settings.orientation_stddev
        bx, by, bz = settings.mag_bias
        # Mounting: the IMU's vectors into the output frame, v_out = R (v - offset) (offset: the gyro's only).
        rot = settings.mount_matrix
        self._rot: Mat3 | None = None if is_identity(rot) else rot
        off = settings.gyro_offset_rad_s
        self._gyro_off = (off[0], off[1], off[2])
        #: the rotation of published vectors and their covariances into the output frame (None: identity)
        self.output_rotation = self._rot
        # None when there is nothing to do: the common case costs one test per sample.
        self._reframe = None if self._rot is None and off == (0.0, 0.0, 0.0) else (rot, self._gyro_off)
        self._sync_raw_clip()
        # Magnetometer: m_out = R_mount R_mag S (m_raw - b), one matrix.
        s = matmul(rot, matmul(settings.mag_matrix, settings.mag_soft_iron))
        self._mag_cal = None if (bx == by == bz == 0.0 and is_identity(s)) else (bx, by, bz, *s)
        self._set_turn()
        self._remove_g = settings.remove_gravity_vector
        self._stateless = settings.stateless
        self._corrected_rate = settings.bias_corrected_rate
        if not settings.mag_online_calibration:
            if self.hard_iron is not None and any(self.hard_iron.status().offset):
                self.filter.magnetometer_changed()  # the applied offset is gone
            self.hard_iron = None
        elif self.hard_iron is None:
            self.hard_iron = HardIronEstimator(settings.mag_online_memory_rad)
        else:
            self.hard_iron.memory_rad = settings.mag_online_memory_rad

    def _set_turn(self) -> None:
        """The output's turn about the world's vertical: ``yaw_offset - declination`` + :attr:`heading_offset_rad`."""
        turn = self.settings.yaw_turn_rad + self.heading_offset_rad
        # q_out = Rz(turn) ⊗ q: a rotation about the output world frame's z (up in ENU/NWU, down in NED), as
        # imu_tools turns its output; applied in one place (_output).
        self._turn = None if turn == 0.0 else (math.cos(0.5 * turn), math.sin(0.5 * turn))

    def _sync_raw_clip(self) -> None:
        """``gyro_range_rad_s`` is the sensor's range, per axis of its raw readings: when the engine rotates the gyro
        or subtracts an offset, the filter's input is no raw reading, and the engine checks the raw one for it."""
        f = self.filter
        self._clip_filter = f if self._reframe is not None and isinstance(f, QuaternionCcf) else None
        if isinstance(f, QuaternionCcf):
            f.raw_clip_check = self._clip_filter is not None

    def _bank_counts(self) -> None:
        """Add the filter's counters to the engine's totals (before the filter's are reset or it is replaced)."""
        f = self.filter
        self._counts_before = [a + b for a, b in zip(self._counts_before, f.counts, strict=True)]
        self._no_acc_before += f.n_no_acc
        self._no_mag_before += f.n_no_mag
        self._nonfinite_before += f.n_nonfinite_resets
        self._clipped_before += getattr(f, 'n_gyro_clipped', 0)

    def replace_filter(self, filt: OrientationFilter) -> None:
        """Run ``filt`` from the next sample on (a fresh estimate); the counters keep counting."""
        self._bank_counts()
        self.filter = filt
        self._sync_raw_clip()
        self._n_far_back = 0
        self._t_ahead = None
        self._t_const = 0.0
        self.latest_stamp_s = -math.inf
        self._stateless_q = None
        self._stateless_heading = False
        self._clear_heading_offset()

    def reset(self) -> None:
        """Fresh filter state (parameters kept); counters keep counting. Magnetometer samples stay paired."""
        f = self.filter
        self._bank_counts()
        self._n_far_back = 0
        self._t_ahead = None
        f.reset()
        self._t_const = 0.0
        self.latest_stamp_s = -math.inf
        self._stateless_q = None
        self._stateless_heading = False
        self._clear_heading_offset()

    def on_mag(self, t_s: float, field: Vec3) -> None:
        """A magnetometer message: stamp (s), field (any unit, body frame), calibrated here before anything else."""
        c = self._mag_cal
        if c is not None:
            mx, my, mz = field[0] - c[0], field[1] - c[1], field[2] - c[2]
            field = (
                c[3] * mx + c[4] * my + c[5] * mz,
                c[6] * mx + c[7] * my + c[8] * mz,
                c[9] * mx + c[10] * my + c[11] * mz,
            )
        self.pairer.add(t_s, field)

    def _to_output_frame(self, gyr: Vec3, acc: Vec3) -> tuple[Vec3, Vec3]:
        """Gyro (offset subtracted) and accelerometer from the IMU's frame into the output frame."""
        assert self._reframe is not None
        (r0, r1, r2, r3, r4, r5, r6, r7, r8), (o0, o1, o2) = self._reframe
        gx, gy, gz = gyr[0] - o0, gyr[1] - o1, gyr[2] - o2
        gyr = (r0 * gx + r1 * gy + r2 * gz, r3 * gx + r4 * gy + r5 * gz, r6 * gx + r7 * gy + r8 * gz)
        if self._rot is not None:
            ax, ay, az = acc
            acc = (r0 * ax + r1 * ay + r2 * az, r3 * ax + r4 * ay + r5 * az, r6 * ax + r7 * ay + r8 * az)
        return gyr, acc

    def _online_hard_iron(self) -> None:
        """Before the filter's update: the magnetometer sample kept at the previous message (every 0.1 s) is paired
        with the orientation the filter reached at it (its own gyro integration: none is done here)."""
        hi = self.hard_iron
        assert hi is not None
        f = self.filter
        c = f.counts
        # No pair spans a restart of the filter (a re-initialisation, a reset: its counts start again, a replaced
        # filter): its orientation jumps there.
        hi.pair(f.quaternion if f.initialized else None,
                (id(f), c[Status.INITIALIZED] + c[Status.REINITIALIZED_AFTER_GAP]), sum(c))
        if hi.jumped:
            f.magnetometer_changed(hi.change_rel)

    def _far_ahead(self, t_s: float, t_last: float) -> float:
        """The stamp to use for a sample stamped far after the latest one (rare path)."""
        t_ahead = self._t_ahead
        if t_ahead is None or t_s < t_ahead:
            # A lone stamp far ahead: the filter sees it as a repeat of the latest stamp (skipped and answered with
            # the current orientation), and nothing moves the clock or the pairing to it.
            self._t_ahead = t_s
            return t_last
        self._t_ahead = None  # the stream goes on from there: a real gap (the filter re-initialises)
        return t_s

    def on_imu(self, t_s: float, gyr: Vec3, acc: Vec3) -> Output | None:  # noqa: C901 - the per-sample path: inlined on purpose
        """An IMU message: stamp (s), rate (rad/s), specific force (m/s²).

        Returns the output, or None before the first usable accelerometer sample (no orientation exists yet).
        """
        self.n_in += 1
        if self._reframe is not None:
            cf = self._clip_filter
            if cf is not None:
                # The range is the sensor's: its raw reading, per axis (the filter runs its recovery on the verdict).
                clip = cf.clip_threshold_rad_s
                gx, gy, gz = gyr
                cf.gyro_clipped_raw = gx >= clip or gx <= -clip or gy >= clip or gy <= -clip or gz >= clip or gz <= -clip
            gyr, acc = self._to_output_frame(gyr, acc)
        t_last = self.latest_stamp_s
        if t_s - t_last > JUMP_AHEAD_S and t_last > -math.inf and t_s - t_last > self.filter.params.max_dt_s:
            t_s = self._far_ahead(t_s, t_last)
        elif self._t_ahead is not None:
            self._t_ahead = None
        if t_s < t_last - JUMP_BACK_RESET_S:
            # Far behind: a stray stamp is skipped by the filter; several in a row mean the clock jumped back (bag
            # loop, simulation reset), and the filter starts over instead of waiting for time to catch up. The
            # magnetometer samples that came with the new stamps stay: the restart initialises heading from them.
            self._n_far_back += 1
            if self._n_far_back >= JUMP_BACK_SAMPLES:
                self.reset()
                self.pairer.restart(t_s, JUMP_BACK_RESET_S)
                self.n_resets_jump += 1
                # The first stamp of the new timeline, as a fresh engine's first sample (a magnetometer sample that
                # comes after it is measured against it: latest_stamp_s).
                self.latest_stamp_s = t_s
        else:
            self._n_far_back = 0
            if t_s > self.latest_stamp_s:
                self.latest_stamp_s = t_s
        mag = self.pairer.get(t_s)
        if t_s > self._hint_until:  # (by header stamps, as the hint's, before constant_dt's clock replaces them)
            self._expire_hint()
        if self._constant_dt > 0.0:
            # Fixed sample period: a synthetic clock advanced per message replaces the header stamps.
            self._t_const += self._constant_dt
            t_s = self._t_const
        self.clock_s = t_s
        f = self.filter
        hi = self.hard_iron
        if hi is not None:
            # Online hard iron: pair the sample kept at the previous message, keep this one when due, subtract the
            # applied offset (HardIronEstimator.correct, written out for a sample not due as in on_chunk: the three
            # change together; a due one goes through correct() itself).
            if hi.pending is not None:
                self._online_hard_iron()
            if mag is not None:
                d = t_s - hi.t_next
                if d >= 0.0 or d < -UPDATE_PERIOD_S:
                    mag = hi.correct(t_s, mag)
                elif (o := hi.offset) is not None:
                    mag = (mag[0] - o[0], mag[1] - o[1], mag[2] - o[2])
        self.paired_mag = mag
        if self._stateless:
            return self._stateless_output(t_s, gyr, acc, mag)
        gx, gy, gz = gyr
        ax, ay, az = acc
        # (update() without its tuple unpacking and one Python call: the floats straight in)
        status = f._update_floats(t_s, gx, gy, gz, ax, ay, az, mag)
        if (self._pending_heading is not None or self.pending_pose is not None or self._anchor is not None) \
                and f.initialized:  # (written out: _heading_todo's call costs more than its three tests)
            self._heading_step(t_s, gyr, status)
        if status >= ANSWERED_BELOW:
            if not f.initialized:
                return None
            self.stale_share += STALE_SHARE_GAIN * (1.0 - self.stale_share)
            self.n_answered_stale += 1
        elif self.stale_share:
            # Exactly 0 again once negligible, so the common path skips this.
            self.stale_share = s if (s := self.stale_share * (1.0 - STALE_SHARE_GAIN)) > 1e-6 else 0.0
        q, variance, bias = f.estimate()
        return self._output(q, status, gyr, acc, variance, bias)

    def on_chunk(  # noqa: C901 - the bulk path's per-sample loop, one function on purpose (a call per sample costs)
        self, is_imu: Sequence[bool], t_s: Sequence[float], v1: Columns, v2: Columns, observe: bool = False,
        answers: bool = True,
    ) -> ChunkAnswers:
        """Many messages in arrival order, as :meth:`on_imu` (``is_imu``: stamp, rate ``v1``, acceleration ``v2``)
        and :meth:`on_mag` (stamp, field ``v1``; its ``v2`` unused) would take them one by one: the same calls into
        the filter with the same floats, the same state after, the answers as columns (:class:`ChunkAnswers`).

        ``v1`` and ``v2`` are columns: (xs, ys, zs), N floats each. One call per chunk: the per-sample steps the
        common settings need are written out in one loop here; a sample that needs anything else (the first one, a
        clock jump, ...) and any other settings go through :meth:`on_imu` itself. Nothing per sample outlives the
        call but floats in flat lists (no tuple per answer: fewer objects for the garbage collector to scan).
        ``observe``: also the paired magnetometer sample and the gate's verdict per IMU sample (``ccf fleet``'s
        health); ``answers`` False: the answers' columns stay empty (the engine's state and counters are the same)."""
        f = self.filter
        ans = ChunkAnswers([], [], [], [], None, None, [] if observe else None, [] if observe else None)
        rows = zip(is_imu, t_s, *v1, *v2, strict=True)
        if (self._reframe is not None or self._stateless or self._constant_dt > 0.0
                or self._remove_g or self._corrected_rate or self._hint_until != math.inf
                or self._heading_todo):
            self._chunk_general(rows, ans, answers)
            return ans
        answered, quats, variances, biases = ans.answered, ans.quaternion, ans.variance, ans.bias
        mags, rejected = ans.paired_mag, ans.mag_rejected
        nan3 = _NAN3
        add_k, add_q, add_v, add_b = answered.append, quats.extend, variances.extend, biases.extend
        on_mag = self.on_mag
        # MagPairer.add and .get written out on its state (kept in locals, written back around on_imu and at the end).
        pairer = self.pairer
        pend = pairer._pending
        push, popleft = pend.append, pend.popleft
        pend_max = pend.maxlen
        tol, timeout = pairer.tolerance_s, pairer.timeout_s
        t_in_use, field = pairer._t_in_use, pairer._field_in_use
        mag_cal = self._mag_cal
        hi = self.hard_iron
        neg_period = -UPDATE_PERIOD_S
        update = f._update_floats  # (update() on the floats: no tuple per sample)
        sd = self._stddev
        var_fixed = (sd * sd,) * 3 if sd > 0.0 else None
        turn = self._turn
        gated = hasattr(f, 'mag_disturbed')
        t_last = self.latest_stamp_s
        # The common path holds while no lone far-ahead stamp waits and no far-behind samples are counted.
        clean = self._t_ahead is None and self._n_far_back == 0
        k = -1  # index among the chunk's IMU samples
        # Counted per chunk, not per sample: the samples through on_imu and the written-out ones left unanswered (the
        # written-out ones and their answers are what remains); the latest through on_imu (index).
        n_slow = n_fast_skipped = 0
        k_slow = -1
        # (Bound once: two tests and two attribute loads less per sample.)
        add_mag = mags.extend if mags is not None else None
        add_rej = rejected.append if rejected is not None else None
        mag: Vec3 | None = None
        t_clock = 0.0
        for imu, t, x1, y1, z1, x2, y2, z2 in rows:
            if not imu:
                if mag_cal is None:
                    if len(pend) == pend_max:
                        pairer.n_pushed_out += 1
                    push((t, (x1, y1, z1)))
                else:
                    on_mag(t, (x1, y1, z1))
                continue
            k += 1
            if not clean or t - t_last > JUMP_AHEAD_S or t < t_last - JUMP_BACK_RESET_S:
                # on_imu itself: the first sample, a jump ahead or back, or what follows one
                n_slow += 1
                k_slow = k
                self.latest_stamp_s = t_last  # (kept in locals by the written-out steps)
                pairer._t_in_use, pairer._field_in_use = t_in_use, field
                out = self.on_imu(t, (x1, y1, z1), (x2, y2, z2))
                f = self.filter
                update = f._update_floats
                t_last = self.latest_stamp_s
                t_in_use, field = pairer._t_in_use, pairer._field_in_use
                pend = pairer._pending
                push, popleft = pend.append, pend.popleft
                pend_max = pend.maxlen
                clean = self._t_ahead is None and self._n_far_back == 0
                if mags is not None and rejected is not None:
                    mags.extend(self.paired_mag or nan3)
                    rejected.append(gated and f.mag_disturbed)
                if out is not None and answers:
                    add_k(k)
                    x, y, z, w = out.orientation_xyzw
                    add_q((w, x, y, z))
                    c = out.covariance
                    add_v((c[0], c[4], c[8]))
                    add_b(out.bias)
                continue
            # on_imu's steps for a stamp within JUMP_AHEAD_S after and JUMP_BACK_RESET_S before the latest one
            t_clock = t
            if t > t_last:
                t_last = t
            if pend:
                limit = t + tol
                # Arrival order is (nearly) stamp order: take samples from the front while they are due.
                while pend and pend[0][0] <= limit:
                    tm, m = popleft()
                    if tm >= t_in_use:
                        t_in_use, field = tm, m
                if pend and not pend[0][0] - t <= timeout:  # (MagPairer.get's rare path: perhaps a stray stamp)
                    pairer._t_in_use, pairer._field_in_use = t_in_use, field
                    pairer.skip_strays_ahead(t, limit)
                    t_in_use, field = pairer._t_in_use, pairer._field_in_use
            mag = None if field is None or t - t_in_use > timeout else field
            if hi is not None:
                # on_imu's online hard iron (pair, keep when due, subtract the offset)
                if hi.pending is not None:
                    self._online_hard_iron()
                if mag is not None:
                    # HardIronEstimator.correct (and its due()) written out for the common case, a sample not due
                    # for pairing (9 in 10); a due one goes through correct() itself. Changes together with them.
                    d = t - hi.t_next
                    if d >= 0.0 or d < neg_period:
                        mag = hi.correct(t, mag)
                    elif (o := hi.offset) is not None:
                        mag = (mag[0] - o[0], mag[1] - o[1], mag[2] - o[2])
            status = update(t, x1, y1, z1, x2, y2, z2, mag)
            if add_mag is not None and add_rej is not None:
                add_mag(mag or nan3)
                add_rej(gated and f.mag_disturbed)
            if status >= ANSWERED_BELOW:
                if not f.initialized:
                    n_fast_skipped += 1
                    continue
                self.stale_share += STALE_SHARE_GAIN * (1.0 - self.stale_share)
                self.n_answered_stale += 1
            elif self.stale_share:
                self.stale_share = s if (s := self.stale_share * (1.0 - STALE_SHARE_GAIN)) > 1e-6 else 0.0
            if not answers:
                continue
            add_k(k)
            q, variance, bias = f.estimate()
            if turn is not None:
                tc, ts = turn
                qw, qx, qy, qz = q
                q = (tc * qw - ts * qz, tc * qx - ts * qy, tc * qy + ts * qx, tc * qz + ts * qw)
            add_q(q)
            add_v(var_fixed or variance)
            add_b(bias)
        # What the written-out steps leave on the engine (counters, latest stamp, clock, pairing).
        n_fast = k + 1 - n_slow
        self.n_in += n_fast
        self.n_out += n_fast - n_fast_skipped
        last_fast = k_slow != k  # (False without IMU samples: both -1)
        self.latest_stamp_s = t_last
        pairer._t_in_use, pairer._field_in_use = t_in_use, field
        if last_fast:
            self.clock_s = t_clock
            self.paired_mag = mag
        return ans

    def _chunk_general(self, rows: Iterator[tuple[Any, ...]], ans: ChunkAnswers, answers: bool) -> None:
        """:meth:`on_chunk` for any settings: :meth:`on_imu` and :meth:`on_mag` message by message."""
        on_imu, on_mag = self.on_imu, self.on_mag
        mags, rejected = ans.paired_mag, ans.mag_rejected
        rates: list[Vec3] = []
        lins: list[Vec3] = []
        k = -1
        for imu, t, x1, y1, z1, x2, y2, z2 in rows:
            if not imu:
                on_mag(t, (x1, y1, z1))
                continue
            k += 1
            out = on_imu(t, (x1, y1, z1), (x2, y2, z2))
            if mags is not None and rejected is not None:
                mags.extend(self.paired_mag or _NAN3)
                rejected.append(bool(getattr(self.filter, 'mag_disturbed', False)))
            if out is None or not answers:
                continue
            ans.answered.append(k)
            x, y, z, w = out.orientation_xyzw
            ans.quaternion.extend((w, x, y, z))
            c = out.covariance
            ans.variance.extend((c[0], c[4], c[8]))
            ans.bias.extend(out.bias)
            if out.angular_velocity is not None:
                rates.append(out.angular_velocity)
            if out.linear_acceleration is not None:
                lins.append(out.linear_acceleration)
        # (Whether an output replaces the rate or acceleration depends on the settings alone: all or none.)
        if rates:
            ans.rate = rates
        if lins:
            ans.linear_acceleration = lins

    def _output(
        self, q: tuple[float, float, float, float], status: int, gyr: Vec3, acc: Vec3,
        variance: Vec3 | None = None, bias: Vec3 | None = None,
    ) -> Output:
        """Shape the orientation ``q`` ([w, x, y, z], world frame) and the sample into an :class:`Output`; the
        covariance is ``orientation_stddev`` if set, else ``variance`` if given, else the filter's; ``bias`` is the
        filter's if not given."""
        f = self.filter
        sd = self._stddev
        vr, vp, vy = (sd * sd,) * 3 if sd > 0.0 else variance or f.orientation_variance
        if bias is None:
            bias = f.gyro_bias
        rate = None
        if self._corrected_rate:
            rate = (gyr[0] - bias[0], gyr[1] - bias[1], gyr[2] - bias[2])
        elif self._reframe is not None:
            rate = gyr  # in the output frame, the offset removed: not the input's
        lin = acc if self._rot is not None else None
        if self._remove_g:
            qw, qx, qy, qz = q
            # World up in the body frame (REP-145: +g up at rest) from the filter's frame; NED's z points down.
            g = -GRAVITY_M_S2 if f.params.world_frame == 'ned' else GRAVITY_M_S2
            lin = (
                acc[0] - g * 2.0 * (qx * qz - qw * qy),
                acc[1] - g * 2.0 * (qy * qz + qw * qx),
                acc[2] - g * (qw * qw - qx * qx - qy * qy + qz * qz),
            )
        turn = self._turn
        if turn is not None:
            c, s = turn
            qw, qx, qy, qz = q
            q = (c * qw - s * qz, c * qx - s * qy, c * qy + s * qx, c * qz + s * qw)
        self.n_out += 1
        # Output(...) without its generated __new__ (a Python call per sample); q to message order as to_xyzw does.
        return _new_output(Output, ((q[1], q[2], q[3], q[0]), (vr, 0.0, 0.0, 0.0, vp, 0.0, 0.0, 0.0, vy), bias,
                                    status, rate, lin))

    def _stateless_output(self, t_s: float, gyr: Vec3, acc: Vec3, mag: Vec3 | None) -> Output | None:
        """imu_tools' ``stateless``: the orientation of this sample's accelerometer (+ magnetometer) alone. The filter
        still runs, so its flags, bias and counts stay meaningful; the covariance is the accelerometer's and
        magnetometer's floors (a heading never taken from a magnetometer: (π/2)²)."""
        f = self.filter
        status = f.update(t_s, gyr, acc, mag)
        if not f.initialized:
            return None
        # Usable or not by this sample's own values, as the filter's input rules judge them (not by the filter's
        # flags: a sample it skipped, for a bad gyro or a repeated stamp, was never looked at and left them stale).
        acc_used = acc_usable(acc)
        if acc_used:
            q = None
            if mag is not None and f.params.use_mag and mag_usable(mag):
                q = quat_from_acc_mag_scalar(*acc, *mag, True)
            if q is not None:
                self._stateless_heading = True
            elif self._stateless_q is not None:
                q = relevel(self._stateless_q, *acc)  # keeps the heading it had
            else:
                q = level_quat(*acc)
                self._stateless_heading = False
            self._stateless_q = q
        # Held (stale) only if this sample's own accelerometer could not give the orientation: a sample the filter
        # skipped still gets its own.
        held = self._stateless_q is None or not acc_used
        self.stale_share += STALE_SHARE_GAIN * (float(held) - self.stale_share)
        if held:
            self.n_answered_stale += 1
        if self._stateless_q is None:
            return None
        p = f.params
        # The floors of the CCF's covariance model (the baselines have none of their own).
        vi = getattr(p, 'incl_sigma_rad', CcfParams.incl_sigma_rad) ** 2
        vh = (
            getattr(p, 'heading_sigma_rad', CcfParams.heading_sigma_rad) ** 2
            if self._stateless_heading else (0.5 * math.pi) ** 2
        )
        q_world = quat_mul_scalar(WORLD_FRAMES[p.world_frame], self._stateless_q)
        return self._output(q_world, status, gyr, acc, (vi, vi, vh))

    # --- the state file (bias_file) ------------------------------------------------------------------------------

    def _warn(self, text: str) -> None:
        self.warnings.append(text)
        if self.on_warning is not None:
            self.on_warning(text)

    @property
    def wants_sensor_frame(self) -> bool:
        """Whether the adapter should call :meth:`set_sensor_frame` (a state file is used and the frame is unknown)."""
        return self.sensor_frame_id is None and bool(self.settings.bias_file)

    def load_state(self, path: str | Path) -> bool:
        """Read a state file; its gyro bias is applied at :meth:`set_sensor_frame` (when the IMU's frame_id is
        known), before the first sample is filtered. A missing file is silent (a first start); an unreadable, stale
        or malformed one is one warning and ignored. Returns whether a state is pending."""
        try:
            state = read_state(path)
            state.gyro_bias()  # malformed sections are found now, not at the first sample
        except FileNotFoundError:
            return False
        except StateFileError as err:
            self._warn(f'bias_file ignored: {err}')
            return False
        age = time.time() - state.stamp
        if age > STATE_MAX_AGE_S:
            self._warn(f'bias_file {path} ignored: written {age / 86400:.0f} days ago (stale: more than '
                       f'{STATE_MAX_AGE_S / 86400:.0f})')
            return False
        self._pending_state = state
        if self.sensor_frame_id is not None:
            self.set_sensor_frame(self.sensor_frame_id)
        return True

    def set_sensor_frame(self, frame_id: str) -> None:
        """The IMU messages' frame_id (adapters call this before the first sample while :attr:`wants_sensor_frame`):
        a pending state file is applied if it was written for this frame, else one warning."""
        self.sensor_frame_id = frame_id
        state, self._pending_state = self._pending_state, None
        if state is None:
            return
        if state.frame_id and frame_id and state.frame_id != frame_id:
            self._warn(f'bias_file ignored: written for frame_id {state.frame_id!r}, this IMU is {frame_id!r}')
            return
        heading = state.sections.get('heading')
        if self.settings.bias_file_heading and heading is not None:
            yaw = heading.get('yaw_rad') if isinstance(heading, dict) else None
            if isinstance(yaw, (int, float)) and not isinstance(yaw, bool) and math.isfinite(yaw):
                self.restore_heading(float(yaw))
            else:
                self._warn(f'bias_file: heading section ignored: {heading!r}')
        hi = state.sections.get('hard_iron')
        if hi is not None and self.hard_iron is not None:
            try:
                self.restore_hard_iron(hi)
            except (KeyError, TypeError, ValueError) as err:
                self._warn(f'bias_file: hard_iron section ignored: {err}')
        gb = state.gyro_bias()
        if gb is None:
            return
        b_imu, sigma = gb
        p = self.filter.params
        init = float(getattr(p, 'bias_sigma_init_rad_s', 0.0)) or math.inf
        walk = float(getattr(p, 'bias_walk_rad_s_sqrt_s', 0.0))
        age = max(time.time() - state.stamp, 0.0)
        # The bias may have wandered since the file was written: its uncertainty grows with the bias walk.
        s = min(math.sqrt((sigma if sigma is not None else init) ** 2 + walk * walk * age), init)
        o = self._gyro_off
        b = apply(self._rot or IDENTITY, (b_imu[0] - o[0], b_imu[1] - o[1], b_imu[2] - o[2]))
        self.filter.set_gyro_bias(b, s if math.isfinite(s) else 0.0)

    def state(self) -> State:
        """What :meth:`save_state` writes: the gyro bias in the IMU's frame (``gyro_offset_rad_s`` included)."""
        b = apply(transpose(self._rot or IDENTITY), self.filter.gyro_bias)
        o = self._gyro_off
        sigma = getattr(self.filter, 'gyro_bias_sigma_rad_s', None)
        st = State(self.sensor_frame_id or '', time.time())
        st.set_gyro_bias((b[0] + o[0], b[1] + o[1], b[2] + o[2]), None if sigma is None else float(sigma))
        if self.settings.bias_file_heading and (yaw := self.heading_state()) is not None:
            st.sections['heading'] = {'yaw_rad': yaw}
        hi = self.hard_iron_state()
        if hi is not None:
            # (In the output frame, where the estimator runs; it is restored only for the same frame_id.)
            st.sections['hard_iron'] = hi
        return st

    def save_state(self, path: str | Path) -> None:
        """Write :meth:`state` to ``path`` atomically (sections other parts wrote there are kept). Nothing is
        written before the filter has an orientation (an unchanged bias would only reset the file's age).

        Raises:
            OSError: not writable.
        """
        if not self.filter.initialized:
            return  # (after a reset too: a zero bias must not replace the learnt one)
        st = self.state()
        try:
            old = read_state(path)
            if not old.frame_id or old.frame_id == st.frame_id:
                st.sections = {**old.sections, **st.sections}
        except (FileNotFoundError, StateFileError):
            pass
        write_state(path, st)
    def hard_iron_status(self) -> HardIronStatus | None:
        """The online hard-iron estimator's status (None: mag_online_calibration is off)."""
        return None if self.hard_iron is None else self.hard_iron.status()

    def hard_iron_state(self) -> dict[str, Any] | None:
        """The online hard-iron estimator's state as plain values, for a state file (None: it is off)."""
        return None if self.hard_iron is None else self.hard_iron.state()

    def restore_hard_iron(self, state: dict[str, Any]) -> None:
        """Continue the online hard-iron estimate from :meth:`hard_iron_state`'s output (ignored when it is off).
        Raises ValueError on a malformed state (the estimate is unchanged then)."""
        hi = self.hard_iron
        if hi is not None:
            hi.restore(state)
            if any(hi.status().offset):
                self.filter.magnetometer_changed()

    def counts(self) -> list[int]:
        """Samples per :class:`~ccf_ros.core.base.Status` since this engine was made."""
        return [a + b for a, b in zip(self._counts_before, self.filter.counts, strict=True)]

    def skipped_by_reason(self) -> dict[str, int]:
        """Counts of samples that could not advance the filter, by reason name (only non-zero ones)."""
        c = self.counts()
        return {Status(i).name.lower(): c[i] for i in range(ANSWERED_BELOW, len(c)) if c[i]}

    def answered(self) -> int:
        """Number of IMU samples answered with an output (those that could not advance the filter included)."""
        return self.n_out

    @property
    def n_no_acc(self) -> int:
        """Samples propagated gyro-only (unusable accelerometer)."""
        return self._no_acc_before + self.filter.n_no_acc

    @property
    def n_no_mag(self) -> int:
        """Samples without heading correction (unusable magnetometer)."""
        return self._no_mag_before + self.filter.n_no_mag

    @property
    def n_nonfinite_resets(self) -> int:
        """Times the filter state became non-finite and was re-initialised."""
        return self._nonfinite_before + self.filter.n_nonfinite_resets

    @property
    def n_gyro_clipped(self) -> int:
        """Gyro samples at ``gyro_range_rad_s`` since the engine was made (filter restarts included)."""
        return self._clipped_before + int(getattr(self.filter, 'n_gyro_clipped', 0))

    # --- heading and motion hint --------------------------------------------------------------------------------
    def _clear_heading_offset(self) -> None:
        """A restart of the estimate (reset, a new filter): the offset set_heading made in 9-D goes (a heading set
        before the filter initialised stays pending: it is the robot's, not the estimate's)."""
        self._anchor = None
        if self.heading_offset_rad:
            self.heading_offset_rad = 0.0
            self._set_turn()

    @property
    def _heading_todo(self) -> bool:
        """Whether on_imu has heading work after the filter's update (a pending heading, an anchor)."""
        return self._pending_heading is not None or self.pending_pose is not None or self._anchor is not None

    def set_heading(self, yaw_rad: float) -> str:
        """Make the output's yaw (Z-Y-X, about the world frame's z, yaw_offset included) ``yaw_rad`` from now on.

        With a magnetometer heading (9-D) the filter stays referenced to north: the output is turned by an offset
        kept until :meth:`reset`. Without (6-D) the filter's state itself is turned. In 9-D before the magnetometer
        gave north the state is turned too, and once it does the gyro carries the set heading on while the filter
        acquires north (``tau_mag_s``): the offset takes their difference, so the output keeps the set heading.
        Before the filter initialised the yaw is kept and applied when it does (:attr:`pending_pose`). Returns
        ``offset``, ``state``, ``pending``, ``ignored: not finite`` or ``ignored: stateless`` (nothing done).
        """
        f = self.filter
        if not math.isfinite(yaw_rad):
            return 'ignored: not finite'
        if self._stateless:
            return 'ignored: stateless'  # (each output is one sample's accelerometer and magnetometer alone)
        if not f.initialized:
            self.pending_pose = yaw_rad
            return 'pending'
        q = f.quaternion
        turn = self._turn
        if turn is not None:
            c, s = turn
            qw, qx, qy, qz = q
            q = (c * qw - s * qz, c * qx - s * qy, c * qy + s * qx, c * qz + s * qw)
        d = math.remainder(yaw_rad - rpy_of(q)[2], 2.0 * math.pi)
        if f.flags.heading_absolute:
            self.heading_offset_rad = math.remainder(self.heading_offset_rad + d, 2.0 * math.pi)
            self._set_turn()
            if self._anchor is not None and self._anchor.yaw is not None:
                self._anchor.yaw += d  # (the heading the gyro carries is the one set now)
            return 'offset'
        f.set_heading(rpy_of(f.quaternion)[2] + d)
        if f.params.use_mag and self._anchor is None:
            self._anchor = _HeadingAnchor(self.heading_offset_rad, float(getattr(f.params, 'tau_mag_s', ANCHOR_S)),
                                          f.quaternion, self.clock_s)
        return 'state'

    def _heading_step(self, t_s: float, gyr: Vec3, status: int) -> None:
        """After an update of the initialised filter (``status``: the update's): pending headings applied, the anchor
        carried on by the samples that advanced the filter."""
        if self._pending_heading is not None:
            self._apply_pending_heading()
        if self.pending_pose is not None:
            yaw, self.pending_pose = self.pending_pose, None
            self.set_heading(yaw)
            return
        a = self._anchor
        if a is None:
            return
        f = self.filter
        dt = t_s - a.t
        if status != _UPDATED_STATUS or not 0.0 < dt <= f.params.max_dt_s:
            # A skipped sample (non-finite gyro, a stamp not after the latest) carries nothing; after a gap or a
            # re-initialisation the gyro has not seen the time between: go on from here.
            if status < ANSWERED_BELOW and dt > 0.0:
                a.t = t_s
                if a.yaw is None:
                    a.q = f.quaternion
            return
        q = f.quaternion
        if a.yaw is None:
            if not f.flags.heading_absolute:
                # Not north-referenced yet: the filter's heading is the gyro's (no magnetometer correction so far).
                a.q, a.t = q, t_s
                return
            # The first sample referenced to north: the heading before it goes on with the gyro from here.
            a.yaw, a.until = rpy_of(a.q)[2], t_s + a.settle_s
        # The rate about the world's vertical: the third row of the body -> world rotation times the corrected rate.
        qw, qx, qy, qz = q
        bx, by, bz = f.gyro_bias
        wz = (2.0 * (qx * qz - qw * qy) * (gyr[0] - bx) + 2.0 * (qy * qz + qw * qx) * (gyr[1] - by)
              + (1.0 - 2.0 * (qx * qx + qy * qy)) * (gyr[2] - bz))
        a.yaw += wz * dt
        a.t = t_s
        self.heading_offset_rad = math.remainder(a.base + a.yaw - rpy_of(q)[2], 2.0 * math.pi)
        self._set_turn()
        if t_s >= a.until:
            self._anchor = None  # north acquired: the offset stays as it is now, as set_heading's in 9-D

    def heading_state(self) -> float | None:
        """The filter's yaw (rad, its world frame, yaw_offset not included) to keep across a restart, or None when
        there is nothing to keep (not initialised, or the heading comes from the magnetometer)."""
        f = self.filter
        if not f.initialized or f.flags.heading_absolute:
            return None
        return rpy_of(f.quaternion)[2]

    def restore_heading(self, yaw_rad: float) -> None:
        """Start from the yaw :meth:`heading_state` gave (e.g. saved before a restart): applied when the filter
        initialises, unless the magnetometer gives it a heading then (a :meth:`set_heading` before it wins)."""
        self._pending_heading = yaw_rad

    def _apply_pending_heading(self) -> None:
        yaw, self._pending_heading = self._pending_heading, None
        f = self.filter
        if yaw is not None and not f.flags.heading_absolute:
            f.set_heading(yaw)

    def on_motion_hint(self, t_s: float, still: bool, timeout_s: float = 0.5) -> float:
        """An outside motion hint stamped ``t_s`` (s): ``still`` or moving. The filter learns the gyro bias at rest
        only while the latest hint says still; a hint counts until ``timeout_s`` after its stamp, on the IMU's
        clock (its header stamps). Returns the latest IMU stamp minus ``t_s`` (s; NaN before the first IMU
        sample): beyond ``timeout_s`` the hint expires at the next IMU sample, below ``-timeout_s`` it counts until
        the IMU stamps reach it (a clock other than the IMU's: the adapter warns)."""
        self.filter.still_hint = still
        self._hint_until = t_s + timeout_s
        return self.latest_stamp_s - t_s if self.latest_stamp_s > -math.inf else math.nan

    def _expire_hint(self) -> None:
        self.filter.still_hint = None
        self._hint_until = math.inf
