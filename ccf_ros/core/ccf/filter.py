"""The cascade's filter: :class:`QuaternionCcf`, the per-sample path (see the package docstring for its stages)."""

from __future__ import annotations

import math
from math import atan2, cos, sin, sqrt
from typing import NamedTuple

from ..base import CommonParams
from ..quaternion import Quat, level_quat, quat_from_acc_mag_scalar, quat_mul_scalar, relevel
from .bias import BiasKalman
from .discretisation import _BlockCoefficients, _cached, _Coefficients
from .mag_gate import STEADY_LOSS, MagGate, about_up
from .params import (
    _DEG,
    BIAS_GATE_SIGMAS,
    BIAS_UPDATE_PERIOD_S,
    CLIP_FRACTION,
    GRAVITY_M_S2,
    MAG_BAND_S,
    MAG_REJECT_SIGMAS,
    REST_BIAS_TOL_RAD_S,
    REST_RELEARN_S,
    CcfParams,
)

#: A field that has steered heading this long (s, the steadiness timer of MagGate) has shown that it stays put.
_STEADY_S = MAG_BAND_S[1]
_PI = math.pi
_INF = math.inf
_TWO_PI = 2.0 * math.pi
_INV_G = 1.0 / GRAVITY_M_S2
#: The smallest weight of a field still blended (MagGate rejects it beyond MAG_REJECT_SIGMAS of its wander).
_W_BLENDED_MIN = 1.0 / MAG_REJECT_SIGMAS
#: Largest NCF heading error the bias estimate uses, rad (see _step).
_HEAD_ERR_MAX = 5.0 * _DEG
_HEAD_ERR_MAX2 = _HEAD_ERR_MAX * _HEAD_ERR_MAX
#: A heading correction larger than this (rad, squared) turns the field summed for the consistency check so far.
_TURN_SUM2 = 1e-6
#: Due at this span (s), so that rounding in the stamps' differences does not make a block of exactly 0.04 s wait
#: for another sample.
_BLOCK_DUE_S = BIAS_UPDATE_PERIOD_S * (1.0 - 1e-6)
_REST_TOL2 = REST_BIAS_TOL_RAD_S**2


def _drift(var: float, bias_step: float, var_arw: float) -> float:
    """Drift variance (rad²) after one uncorrected step: the bias error adds linearly to the error's standard
    deviation (``bias_step`` = bias uncertainty x dt, rad), the gyro noise adds ``var_arw`` (rad²)."""
    return var + var_arw + bias_step * (bias_step + 2.0 * sqrt(var))


class CcfState(NamedTuple):
    """The per-sample state of :class:`QuaternionCcf` besides its orientation, by stage; the defaults are the reset
    value. The filter keeps it as a plain tuple in this order (``QuaternionCcf._x``; :attr:`QuaternionCcf.state`
    names it): CPython 3.11 unpacks a tuple subclass ~3x slower than a tuple, and building one costs a call, ~0.5 µs a
    sample in all (benchmarks/state_tuple.py)."""

    # Gravity low-pass (body frame): the filtered specific force g_lp, m/s², and its rate, m/s³.
    g_lp_x: float = 0.0
    g_lp_y: float = 0.0
    g_lp_z: float = GRAVITY_M_S2
    g_rate_x: float = 0.0
    g_rate_y: float = 0.0
    g_rate_z: float = 0.0
    # NCF: its attitude's offset dn from the LCF's, rad, world frame (east, north, up).
    dn_e: float = 0.0
    dn_n: float = 0.0
    dn_u: float = 0.0
    # dn_u low-passed over tau_ncf_s, rad, and the stamp (s; inf: none) since which dn_u, beyond ±5°, has stayed
    # within its tolerance of it: whether the stages' heading difference is a bias's steady lag (_bias_lag).
    dn_u_lp: float = 0.0
    lag_since_s: float = math.inf
    # The gyro bias (the NCF's integral), rad/s, body frame.
    bias_x: float = 0.0
    bias_y: float = 0.0
    bias_z: float = 0.0
    # The bias update's current block: its span, s, and samples; the NCF heading errors summed, rad, and how many.
    block_s: float = 0.0
    block_n: int = 0
    head_err_sum_rad: float = 0.0
    head_err_n: int = 0
    # Magnetometer gate, this block: the field through the attitude summed (east, north, up, the sensor's unit) and
    # how many samples; the LCF's corrections summed, rad, body frame (they turn the field seen through the attitude).
    field_e: float = 0.0
    field_n: float = 0.0
    field_u: float = 0.0
    field_count: int = 0
    corr_x: float = 0.0
    corr_y: float = 0.0
    corr_z: float = 0.0


#: Where the bias begins in :class:`CcfState`.
_I_BIAS = CcfState._fields.index('bias_x')
_I_DN = CcfState._fields.index('dn_e')
_I_LAG = CcfState._fields.index('lag_since_s')


class QuaternionCcf(MagGate):
    """NCF -> LCF cascade on unit quaternions; see the package docstring (:mod:`ccf_ros.core.ccf`).

    State (all reset by :meth:`reset`): LCF orientation ``q``, the per-sample :class:`CcfState` (gravity low-pass,
    NCF offset, bias, the current bias-update block), the bias filter (:class:`~ccf_ros.core.ccf.bias.BiasKalman`:
    covariance, observation model), rest-detector low-passes and timer, the magnetometer gate's reference and
    candidate (:class:`~ccf_ros.core.ccf.mag_gate.MagGate`), drift variances (rad²).
    """

    name = 'ccf'
    __slots__ = (
        '_acc_lp',
        '_bcoef',
        '_bcoef_cache',
        '_bias_rested',
        '_coef',
        '_coef_cache',
        '_coef_prev',
        '_gyro_lp',
        '_head_lag_tau2',
        '_head_var',
        '_heading_known',
        '_incl_var',
        '_kf',
        '_n_init',
        '_raw_clip',
        '_rest_s',
        '_var_incl',
        '_x',
        'clip_threshold_rad_s',
        'gyro_clipped_raw',
        'n_gyro_clipped',
    )
    params: CcfParams

    def __init__(self, params: CcfParams | None = None) -> None:
        # (Before the base class applies the parameters: the coefficients read it.)
        self._raw_clip: bool = False
        #: with :attr:`raw_clip_check`: the caller's verdict on the next sample's raw gyro (at the range or not)
        self.gyro_clipped_raw: bool = False
        super().__init__(params if params is not None else CcfParams())

    def _apply_params(self, params: CommonParams) -> None:
        super()._apply_params(params)
        r = self.params.gyro_range_rad_s
        #: a raw gyro reading at or beyond this (rad/s, per axis) is at the range (inf: no range known)
        self.clip_threshold_rad_s: float = CLIP_FRACTION * r if r > 0.0 else math.inf
        # The variance floors of orientation_variance, rad² (read per output: computed once here, the same products).
        p = self.params
        self._incl_var = p.incl_sigma_rad * p.incl_sigma_rad
        self._head_var = p.heading_sigma_rad * p.heading_sigma_rad
        # Without the bias's heading rows (bias_from_mag or motion_bias false) the heading blend is proportional only
        # (no integral on heading while moving): a bias error e along world up leaves heading behind by e x tau_mag_s
        # (/ the field's weight), which carries on while the field is rejected, so the heading variance adds
        # tau_mag_s² times the bias's variance along up (s²; 0: the heading rows remove that lag, as an integral does).
        self._head_lag_tau2 = 0.0 if p.bias_from_mag and p.motion_bias else p.tau_mag_s * p.tau_mag_s

    @property
    def raw_clip_check(self) -> bool:
        """Whether the caller checks ``gyro_range_rad_s`` itself, on the sensor's raw readings, and tells the verdict
        per sample in :attr:`gyro_clipped_raw` before :meth:`update`. Needed when the filter's input is not the raw
        reading (the engine's mount rotation and gyro offset: a rotated reading is at no axis's range, an unclipped
        one may be beyond it); the filter's own check of its input is off then. False by default."""
        return self._raw_clip

    @raw_clip_check.setter
    def raw_clip_check(self, on: bool) -> None:
        if on != self._raw_clip:
            self._raw_clip = on
            self.gyro_clipped_raw = False
            self._rebuild_coefficients()  # (they hold the filter's own threshold)

    def _reset_state(self) -> None:
        # (Counts are ints among the floats.)
        self._x: tuple[float, ...] = tuple(CcfState())
        self._coef_cache: dict[int, _Coefficients] = {}
        self._bcoef_cache: dict[int, _BlockCoefficients] = {}
        self._coef = self._coef_prev = self._coefficients(0.01)
        self._bcoef = self._block_coefficients(BIAS_UPDATE_PERIOD_S)
        self._gyro_lp = (0.0, 0.0, 0.0)
        self._acc_lp = (0.0, 0.0, 0.0)
        self._rest_s = 0.0
        self._n_init = 0
        # (Before _forget_mag_reference, which reads nothing of it, for symmetry with _init.)
        self._kf = BiasKalman(self.params.bias_sigma_init_rad_s**2)
        self._forget_mag_reference()
        self._var_incl = 0.0
        self._var_head = 0.0
        self._heading_known = False
        # Whether the bias was seen at rest since the start (then a steady rate must agree with it to be a rest).
        self._bias_rested = False
        #: Gyro samples at gyro_range_rad_s since the start.
        self.n_gyro_clipped = 0

    def _coefficients(self, dt: float) -> _Coefficients:
        """The per-sample coefficients for a sample period of ``dt`` s (> 0)."""
        return _cached(self._coef_cache, dt, lambda key: _Coefficients.of(self.params, key, not self._raw_clip))

    def _block_coefficients(self, t: float) -> _BlockCoefficients:
        """The bias update's constants for a block spanning ``t`` s (> 0)."""
        return _cached(self._bcoef_cache, t, lambda key: _BlockCoefficients.of(self.params, key))

    def _rebuild_coefficients(self) -> None:
        """The per-sample coefficients built again (the cache and the previous bin's forgotten), in the same bin: at
        its middle."""
        self._coef_cache = {}
        self._coef = self._coef_prev = self._coefficients(math.sqrt(self._coef.dt_lo * self._coef.dt_hi))

    def _params_changed(self) -> None:
        self._rebuild_coefficients()
        self._end_lag()
        self._bcoef_cache = {}
        # The bin's middle: the same bin as before the change.
        self._bcoef = self._block_coefficients(math.sqrt(self._bcoef.t_lo * self._bcoef.t_hi))
        if not self.params.rest_bias:
            self.at_rest = False
            self._rest_s = 0.0
        elif self._rest_s < self.params.rest_min_s:
            # A longer rest_min_s: not at rest until the timer reaches it (the NCF integral runs meanwhile).
            self.at_rest = False
        if self._mag_have_ref and self._mag_learn_s <= 0.0:
            recheck = self._mag_recheck
            if recheck:
                # (Measured again: the bounds that decide meanwhile are kept with it.)
                self._mag_recheck = (*self._bounds(*self._mag_ref), *recheck[4:])
            else:
                self._mag_bounds = self._bounds(*self._mag_ref)

    def _init(self, ax: float, ay: float, az: float, mx: float, my: float, mz: float, mag_ok: bool) -> None:
        q: Quat | None = quat_from_acc_mag_scalar(ax, ay, az, mx, my, mz, mag_ok)
        p = self.params
        if q is not None:
            # The field at (re)initialisation begins the reference of the disturbance gate (a mean, see above).
            an = sqrt(ax * ax + ay * ay + az * az)
            n = sqrt(mx * mx + my * my + mz * mz)
            self._set_mag_reference(n, (mx * ax + my * ay + mz * az) / (n * an))
            self._var_head = 0.0
            self._heading_known = True
        else:
            # No heading from this sample: a re-initialisation keeps the heading it had (6-D: relative heading goes
            # on), a first initialisation starts at heading zero. The reference field is learnt from the next
            # usable magnetometer samples.
            q = relevel(self._q, ax, ay, az) if self.initialized else level_quat(ax, ay, az)
            self._forget_mag_reference()
            if not self.initialized:
                self._var_head = 0.0 if not p.use_mag else (math.pi / 2) ** 2
                self._heading_known = False
        self._q = q
        bx, by, bz = self._x[_I_BIAS:_I_BIAS + 3]
        self._x = tuple(CcfState(g_lp_x=ax, g_lp_y=ay, g_lp_z=az, bias_x=bx, bias_y=by, bias_z=bz))
        self._gyro_lp = (bx, by, bz)
        self._rest_s = 0.0
        self.at_rest = False
        self._var_incl = 0.0
        # The bias and its covariance are kept; the observation model starts from the new attitude.
        self._kf.model = None
        # Start-up: the blends begin as running means (gain 1/n) and hand over to their time constants once 1/n
        # falls below them, so the first seconds average the samples instead of trusting the first one.
        self._n_init = 1

    def _heading_absolute(self) -> bool:
        return self._heading_known

    def _step(  # noqa: C901 - the per-sample hot path, one function on purpose (calls cost as much as the maths)
        self,
        dt: float,
        gx: float,
        gy: float,
        gz: float,
        ax: float,
        ay: float,
        az: float,
        acc_n2: float,
        mx: float,
        my: float,
        mz: float,
        mag_n2: float,
    ) -> None:
        """One sample, in the stages of the package docstring (numbered below). One function on purpose: a Python
        call costs 50-100 ns and the whole update ~10 µs, so a helper per stage would cost more than this split's
        budget of 5 %; only rare paths (start-up, clipping, rejected magnetometer samples, rest bookkeeping) and the
        per-block updates (bias, field consistency) are calls."""
        c = self._coef
        if not c.dt_lo <= dt <= c.dt_hi:
            # A period on a bin's edge (400 Hz is one) alternates between two bins with the stamps' rounding: the
            # previous bin is tried before the cache's lookup (the same coefficients, without its calls).
            p = self._coef_prev
            self._coef_prev = c
            c = self._coef = p if p.dt_lo <= dt <= p.dt_hi else self._coefficients(dt)
        clip = c.clip  # (inf with raw_clip_check: the caller's verdict is gyro_clipped_raw)
        # (inf also without a known range, the default: then the six comparisons are skipped; the gyro is finite)
        if ((clip != _INF and (gx >= clip or gx <= -clip or gy >= clip or gy <= -clip or gz >= clip or gz <= -clip))
                or self.gyro_clipped_raw):
            self._gyro_clipped(c.var_clip)
        qw, qx, qy, qz = self._q
        # CcfState's fields, in its order (a plain tuple: see CcfState).
        (fx, fy, fz, fdx, fdy, fdz, dnx, dny, dnz, dlp, lag_t, bx, by, bz, blk_t, blk_n, h_sum, h_n,
         we, wn, wu, w_n, scx, scy, scz) = self._x
        # -- 1. Attitude and errors.
        # Rows of the body->world rotation matrix: world east (r0), north (r1) and up (v) in body coordinates.
        # (Twice the products: x2 = 2 qx etc. saves the factor 2 of every matrix element.)
        x2, y2, z2 = qx + qx, qy + qy, qz + qz
        xx, yy, zz = qx * x2, qy * y2, qz * z2
        xy, xz, yz = qx * y2, qx * z2, qy * z2
        wx, wy, wz = qw * x2, qw * y2, qw * z2
        r0x, r0y, r0z = 1.0 - (yy + zz), xy - wz, xz + wy
        r1x, r1y, r1z = xy + wz, 1.0 - (xx + zz), yz - wx
        sxy = xx + yy  # (also in the renormalisation below, evaluated in the same order: (xx + yy) + zz)
        vx, vy, vz = xz - wy, yz + wx, 1.0 - sxy
        # LCF tilt error e: rotation (rad, body) taking the filtered gravity direction onto the estimated up;
        # divided by standard gravity, not |g_lp|, so the correction stays linear in the specific force.
        ig = _INV_G
        ex = (fy * vz - fz * vy) * ig
        ey = (fz * vx - fx * vz) * ig
        ez = (fx * vy - fy * vx) * ig
        ni = self._n_init
        if ni:
            ni += 1
            kn = 1.0 / ni
            k_acc = kn if kn > c.k_acc else c.k_acc
            k_mag = kn if kn > c.k_mag else c.k_mag
            # The low-pass starts as a running mean too (0.0: the Butterworth filter has taken over).
            k_lp = kn if kn > c.k_lp else 0.0
            if kn > c.k_min:
                self._n_init = ni
            else:
                self._n_init = 0
                if self._mag_recheck == ():
                    # The reference learnt while the tilt converged: its dip is measured again from here.
                    self._mag_recheck_begin()
        else:
            k_acc = c.k_acc
            k_mag = c.k_mag
            k_lp = 0.0
        cx = k_acc * ex
        cy = k_acc * ey
        cz = k_acc * ez
        # NCF tilt error: its attitude is exp(dn) ⊗ q (dn: a small world-frame rotation), so its tilt error is e
        # minus the horizontal part of dn seen in the body frame.
        nx = ex - dnx * r0x - dny * r1x
        ny = ey - dnx * r0y - dny * r1y
        nz = ez - dnx * r0z - dny * r1z
        # -- 2. Magnetometer gate and heading; the drift variances of what is not corrected.
        hn = kd = kdn = 0.0
        if mag_n2:
            # The sample is a mean over the step, like the accelerometer's: the field in the frame of mid-interval.
            # The attitude here is the step's start, so carry it back half the gyro step, m' = m + p x m.
            # ((g - b) * 0.5 * dt: the factor 0.5 is exact in either place, so one product of it serves all three.)
            hdt = 0.5 * dt
            px = (gx - bx) * hdt
            py = (gy - by) * hdt
            pz = (gz - bz) * hdt
            mx, my, mz = mx + (py * mz - pz * my), my + (pz * mx - px * mz), mz + (px * my - py * mx)
            # The field in world coordinates through the attitude: east, north, up.
            me = r0x * mx + r0y * my + r0z * mz
            mn = r1x * mx + r1y * my + r1z * mz
            mu = vx * mx + vy * my + vz * mz
            norm = sqrt(mag_n2)
            sin_dip = mu / norm
            lo2, hi2, lo_dip, hi_dip = self._mag_bounds
            # Whether the field stays put in the world is judged per block on every sample, those the norm and dip
            # gate rejects too: a field that turns as the sensor moves must not look new (and steady) each time it
            # passes the gate again somewhere else.
            we += me
            wn += mn
            wu += mu
            w_n += 1
            # (Whether the previous magnetometer sample was rejected, read before the gate below may set it; an
            # accepted sample leaves it False either way: _mag_rejected accepts one through _set_mag_reference, or
            # without touching it while the reference is learnt or measured again, and a True left is reset below.)
            was_disturbed = self.mag_disturbed
            if (lo2 <= mag_n2 <= hi2 and lo_dip <= sin_dip <= hi_dip) or self._mag_rejected(
                dt, norm, sin_dip, me, mn, mu, gx - bx, gy - by, gz - bz
            ):
                mag_ok = self._mag_consistent
            else:
                mag_ok = False
            if mag_ok:
                if was_disturbed:
                    self.mag_disturbed = False
                # Horizontal field in the world frame must point to +y (north in ENU). The correction is a rotation
                # about world up (v in body coordinates): heading only, never tilt.
                d = atan2(me, mn)
                kh = k_mag * self._mag_weight
                # The blend's own share of the correction: the NCF's heading moves with the rest (below).
                kdn = kh * d
                vh = self._var_head
                if vh:
                    # The heading has drifted (or was re-set by a new field) since it was last corrected: the blend
                    # takes a field sample with the Kalman gain of that uncertainty against the field's own
                    # (heading_sigma² per tau_mag_s of samples), so that it re-acquires within a second, not tau_mag_s.
                    # A field that wanders (weight < 1) is as much noisier here as in the blend. Not before the field
                    # has steered heading steadily for _STEADY_S (except in the start-up, whose heading is a running
                    # mean): a field that returns after a rejection may be one that turns as the sensor moves through
                    # it, passing the check for a few seconds before it turns again, and a re-acquisition would take
                    # its direction of the moment whole; until then only the blend corrects heading.
                    if ni or self._mag_steady_s >= _STEADY_S:
                        kv = vh / (vh + c.r_head / (self._mag_weight * self._mag_weight))
                    else:
                        kv = 0.0
                    if kv > kh:
                        kh = kv
                        vh *= 1.0 - kv
                    else:
                        vh *= c.keep_head
                    # Exactly zero again once negligible, so the common path skips this.
                    self._var_head = vh if vh > 1e-14 else 0.0
                    self._heading_known = True
                kd = kh * d
                if kd * kd > _TURN_SUM2:
                    # A large correction (heading re-acquired, the start-up's running mean): the field summed this
                    # block so far, seen through the attitude before it, turns with it, so that the block's mean is
                    # one direction (else a 0.5 rad re-acquisition seeded the band 7° off, and it read that as the
                    # field's motion for its 8 s). Steady corrections are ~1e-5 rad at 100 Hz; at a few Hz, or with a
                    # noisy magnetometer, an occasional sample takes this too (exactly, and at the cost of a cos and
                    # a sin).
                    we, wn = about_up(cos(kd), sin(kd), we, wn)
                # NCF heading error (its heading is the LCF's turned by dnz about world up). Its own heading takes
                # all of it; the bias estimate only what is within ±_HEAD_ERR_MAX while the two stages' headings
                # agree within it too, or differ by a bias's steady lag (_bias_lag; dnz low-passed over tau_ncf_s
                # for it). A larger error, or another larger dnz, means the heading has not converged yet (a start,
                # a new field: the NCF turns faster than the LCF), and the decay would look like bias.
                dlp += c.k_ncf * (dnz - dlp)
                hn = d - dnz
                if hn > _PI:  # the NCF's heading takes all of it: the short way round
                    hn -= _TWO_PI
                elif hn < -_PI:
                    hn += _TWO_PI
                if dnz * dnz < _HEAD_ERR_MAX2:
                    # (A steady lag beyond it must be held anew: its timer ends here.)
                    lag_t = _INF
                    use = hn * hn < _HEAD_ERR_MAX2
                else:
                    use, lag_t = self._bias_lag(dnz, dlp, hn, lag_t)
                if use:
                    h_sum += hn
                    h_n += 1
                cx += kd * vx
                cy += kd * vy
                cz += kd * vz
            else:
                self.mag_disturbed = True
                # Only runs of rejected samples count against steadiness, not single ones (a noisy magnetometer's
                # outliers): when the previous magnetometer sample was rejected too, the time since it counts. Per
                # magnetometer sample, not per IMU sample: a slower magnetometer's sample comes once (a missing one
                # in between) or held with each IMU sample (the engine's pairing), whose copies have its norm.
                if mag_n2 != self._mag_rej_n2:
                    t = self._t_last
                    if was_disturbed:
                        self._mag_steady_s -= STEADY_LOSS * (t - self._mag_rej_t)
                    self._mag_rej_t = t
                    self._mag_rej_n2 = mag_n2
                self._var_head = _drift(self._var_head, c.sigma_init * sqrt(self._kf.u) * dt, c.var_arw)
        else:
            self._var_head = _drift(self._var_head, c.sigma_init * sqrt(self._kf.u) * dt, c.var_arw)
        if acc_n2:
            vi = self._var_incl
            if vi:
                self._var_incl = vi * c.keep_incl if vi > 1e-14 else 0.0
        else:
            self._var_incl = _drift(self._var_incl, c.sigma_init * sqrt(self._kf.u) * dt, c.var_arw)
        # -- 3. Bias: the NCF integral, the rest, the clamp.
        # NCF integral: a Kalman update of the bias once the block of samples spans BIAS_UPDATE_PERIOD_S.
        blk_t += dt
        blk_n += 1
        # The LCF's corrections this block (rad, body): they turn the field seen through the attitude.
        scx += cx
        scy += cy
        scz += cz
        if blk_t >= _BLOCK_DUE_S:
            cb = self._bcoef
            if not cb.t_lo <= blk_t <= cb.t_hi:
                cb = self._bcoef = self._block_coefficients(blk_t)
            steady = self._mag_steady_s + blk_t
            steady = self._mag_steady_s = 0.0 if steady < 0.0 else (_STEADY_S if steady > _STEADY_S else steady)
            bx, by, bz = self._kf.update(
                cb, blk_n, bx, by, bz, (r0x, r0y, r0z, r1x, r1y, r1z, vx, vy, vz), nx, ny, nz,
                # The heading rows only from a field that has steered heading steadily for _STEADY_S: one that turns
                # slowly through the check's allowance for a few seconds would teach the bias its turn, which nothing
                # corrects while it is rejected afterwards. None at all without bias_from_mag.
                (h_sum, h_n, self._mag_ref[1], self._mag_weight)
                if h_n and steady >= _STEADY_S and cb.bias_from_mag else None,
                gx * gx + gy * gy + gz * gz,
                # Not during the start-up (ni): the errors then are the initial attitude's, not the bias's (a start in
                # strong motion leaves the tilt tens of degrees off for seconds, and its decay, read as drift, taught
                # the bias degrees per second), except in 6-D once the tilt is found (k_lp 0) while the NCF's tilt
                # error is one a bias could hold (cb.start_tilt2); not at rest, where the low-passed gyro below is far
                # more informative; not without an accelerometer.
                acc_n2 != 0.0 and not self.at_rest
                and (not ni or (not k_lp and nx * nx + ny * ny + nz * nz < cb.start_tilt2)),
                self.at_rest,
            )
            if self._mag_learn_s > 0.0:
                # The reference field is being learnt: the tilt's corrections meanwhile (east, north; MagGate
                # _mag_rejected: whether its dip is measured again after the start-up).
                te, tn = self._mag_learn_tilt
                self._mag_learn_tilt = (te + r0x * scx + r0y * scy + r0z * scz, tn + r1x * scx + r1y * scy + r1z * scz)
            if w_n and k_lp == 0.0:
                # Once the tilt is found (the gravity low-pass has handed over from its running mean), not only after
                # the whole start-up: the LCF's corrections are taken out, so the field's own motion shows as well
                # while heading is still a running mean (a sensor started in a field that varies with position must
                # not drag it).
                self._mag_consistency(
                    we, wn, wu,
                    r0x * scx + r0y * scy + r0z * scz, r1x * scx + r1y * scy + r1z * scz, vx * scx + vy * scy + vz * scz,
                )
            blk_t = h_sum = we = wn = wu = scx = scy = scz = 0.0
            blk_n = h_n = w_n = 0
        if c.rest_bias and acc_n2:
            # Rest: the accelerometer within rest_acc_m_s2 of its own low-pass in the body (tested first: it fails
            # first while moving; not the gravity the gyro carries, which an unknown offset of several °/s turns
            # away while the IMU lies still), and the gyro within rest_gyro_rad_s of its low-pass. A sample without
            # a usable accelerometer neither extends nor ends a rest (one corrupted message in a hundred would
            # otherwise never let a rest last rest_min_s).
            rest_s = self._rest_s
            if rest_s:
                alx, aly, alz = self._acc_lp
                dax = ax - alx
                day = ay - aly
                daz = az - alz
                acc_still = dax * dax + day * day + daz * daz < c.rest_acc2
            else:
                # A possible rest begins: both low-passes start from this sample (they are not kept while moving).
                # Its deviations from them are then 0.0 (x - x of a finite x), written out: the tests compare 0.0, and
                # the low-passes after their update are the sample + 0.0 (k * 0.0 added; a -0.0 becomes 0.0 as there).
                acc_still = c.rest_acc2 > 0.0
            # A motion hint saying "moving" (odometry) rules rest out: a slow steady turn is not learnt as bias.
            if acc_still and self.still_hint is not False:
                k = c.k_rest
                m2 = c.bias_max2
                if rest_s:
                    glx, gly, glz = self._gyro_lp
                    # d = sample - previous low-pass; the deviation from the updated low-pass is (1 - k) d, which the
                    # gyro threshold in c accounts for.
                    dgx = gx - glx
                    dgy = gy - gly
                    dgz = gz - glz
                    glx += k * dgx
                    gly += k * dgy
                    glz += k * dgz
                    # The low-passed gyro must be a believable bias: within the clamp, per axis as the clamp is.
                    still = (dgx * dgx + dgy * dgy + dgz * dgz < c.rest_gyro2
                             and glx * glx < m2 and gly * gly < m2 and glz * glz < m2)
                else:
                    # (The low-pass, the sample + 0.0, squares as the sample does: tested before it is made.)
                    still = c.rest_gyro2 > 0.0 and gx * gx < m2 and gy * gy < m2 and gz * gz < m2
                    if still:
                        glx, gly, glz = gx + 0.0, gy + 0.0, gz + 0.0
                if still:
                    # The low-passes are read by the next sample only while the timer runs: stored only here.
                    if rest_s:
                        self._acc_lp = (alx + k * dax, aly + k * day, alz + k * daz)
                    else:
                        self._acc_lp = (ax + 0.0, ay + 0.0, az + 0.0)
                    self._gyro_lp = (glx, gly, glz)
                    # 1e-12 s keeps the timer non-zero (the low-pass continues) from the first sample on.
                    rest_s = self._rest_s = rest_s + dt + 1e-12
                    if rest_s >= c.rest_min_s:
                        rex = glx - bx
                        rey = gly - by
                        rez = glz - bz
                        if self.still_hint or not self._bias_rested:
                            agrees = self._rest_agrees(rex, rey, rez)
                        else:
                            # _rest_agrees' common case (the bias seen at rest before, no hint) written out: they
                            # change together.
                            p00, _, _, p11, _, p22 = self._kf.p
                            agrees = (rex * rex + rey * rey + rez * rez < _REST_TOL2 + 9.0 * (p00 + p11 + p22)
                                      or rest_s >= REST_RELEARN_S)
                    else:
                        agrees = False
                    if agrees:
                        # At rest the low-passed gyro *is* the bias: pull the estimate there (its covariance relaxes
                        # to bias_sigma_rest² in BiasKalman.update).
                        self.at_rest = True
                        bx += k * (glx - bx)
                        by += k * (gly - by)
                        bz += k * (glz - bz)
                    elif self.at_rest:
                        # Steady, but no longer at the bias seen: a slow turn began.
                        self.at_rest = False
                elif rest_s:
                    self._rest_s = 0.0
                    self._end_rest()
            elif rest_s:
                self._rest_s = 0.0
                self._end_rest()
        # Anti-windup: the estimate never leaves ±bias_max per axis (tested per axis only when the norm says it may).
        if bx * bx + by * by + bz * bz > c.bias_max2:
            m = c.bias_max
            bx = max(-m, min(m, bx))
            by = max(-m, min(m, by))
            bz = max(-m, min(m, bz))
        # -- 4. LCF output.
        # LCF: integrate the bias-corrected rate plus the blend correction: q <- q ⊗ exp(h).
        rx = (gx - bx) * dt
        ry = (gy - by) * dt
        rz = (gz - bz) * dt
        hx = 0.5 * (rx + cx)
        hy = 0.5 * (ry + cy)
        hz = 0.5 * (rz + cz)
        n2 = hx * hx + hy * hy + hz * hz
        if n2 < 1e-4:
            # Taylor series of cos(x) and sin(x)/x to x⁴; the first omitted terms are below 2e-15 for |x| < 0.01.
            # (Not shorter: the published quaternion's norm is exp(h)'s, and a deficit of even 1e-10 reads as a 1e-3°
            # rotation to anyone who takes the angle between two quaternions as 2 acos|q1·q2|.)
            cw = 1.0 - n2 * (0.5 - n2 * (1.0 / 24.0))
            s = 1.0 - n2 * (1.0 / 6.0 - n2 * (1.0 / 120.0))
        else:
            n = sqrt(n2)
            cw = cos(n)
            s = sin(n) / n
        # The gyro's share of the step alone, p (g_lp follows the gyro only, not the LCF correction c, ~1e-5 rad).
        # Its cos is taken as the full step's cw, which leaves the rotation orthogonal to second order in |c| (and
        # more exact than rotating by h and undoing c, which left ~|r x c| / 2).
        # (Also twice it, p2 = s r exactly: scaling by 2 is exact, so the cross products below, 2 (v x p) = v x p2, take
        # p2 instead of a factor 2.0 each: the same floats, four products fewer.)
        p2x = s * rx
        p2y = s * ry
        p2z = s * rz
        px = 0.5 * p2x
        py = 0.5 * p2y
        pz = 0.5 * p2z
        # q's norm is 1 to rounding (a product of unit quaternions): its first-order inverse 1.5 - 0.5 |q|² (exact
        # to ~1e-30 there, no square root), folded into exp(h), renormalises the product.
        inv = 1.5 - 0.5 * qw * qw - 0.25 * (sxy + zz)
        hw = cw * inv
        s *= inv
        hx *= s
        hy *= s
        hz *= s
        self._q = (
            qw * hw - qx * hx - qy * hy - qz * hz,
            qw * hx + qx * hw + qy * hz - qz * hy,
            qw * hy - qx * hz + qy * hw + qz * hx,
            qw * hz + qx * hy - qy * hx + qz * hw,
        )
        # -- 5. Gravity low-pass.
        # g_lp and its rate into the new body frame, v' = R(p)^T v = v - 2 cw (p x v) + 2 p x (p x v).
        tx = fy * p2z - fz * p2y
        ty = fz * p2x - fx * p2z
        tz = fx * p2y - fy * p2x
        fx += cw * tx + (ty * pz - tz * py)
        fy += cw * ty + (tz * px - tx * pz)
        fz += cw * tz + (tx * py - ty * px)
        tx = fdy * p2z - fdz * p2y
        ty = fdz * p2x - fdx * p2z
        tz = fdx * p2y - fdy * p2x
        fdx += cw * tx + (ty * pz - tz * py)
        fdy += cw * ty + (tz * px - tx * pz)
        fdz += cw * tz + (tx * py - ty * px)
        if acc_n2:
            # The sample is a mean over the step (gravity in the frame of mid-interval): carry it the half step to
            # the step's end, v' = v - p x v (p = r/2 to ~1e-5), then filter it in.
            ax, ay, az = ax - (py * az - pz * ay), ay - (pz * ax - px * az), az - (px * ay - py * ax)
            if k_lp:
                # Start-up: a running mean, no rate yet.
                fx += k_lp * (ax - fx)
                fy += k_lp * (ay - fy)
                fz += k_lp * (az - fz)
                fdx = fdy = fdz = 0.0
            else:
                # Butterworth low-pass, exact for a sample held over the step.
                a, p12, p21, p22 = c.lp_a, c.lp12, c.lp21, c.lp22
                ax = fx - ax
                ay = fy - ay
                az = fz - az
                fx += p12 * fdx - a * ax
                fy += p12 * fdy - a * ay
                fz += p12 * fdz - a * az
                fdx = p21 * ax + p22 * fdx
                fdy = p21 * ay + p22 * fdy
                fdz = p21 * az + p22 * fdz
        # -- 6. NCF offset.
        # NCF offset (world frame, unchanged by the common gyro step): dn += R (c_ncf - c_lcf); its vertical part is
        # the NCF's own heading (moved by the magnetometer only).
        k = c.k_ncf
        ux = k * nx - cx
        uy = k * ny - cy
        uz = k * nz - cz
        self._x = (  # CcfState's order
            fx, fy, fz, fdx, fdy, fdz,
            dnx + r0x * ux + r0y * uy + r0z * uz,
            dny + r1x * ux + r1y * uy + r1z * uz,
            # (A re-acquisition's share, kd - kdn, turns both stages: it is no drift of the NCF's.)
            dnz + k * hn - kdn, dlp, lag_t,
            bx, by, bz, blk_t, blk_n, h_sum, h_n, we, wn, wu, w_n, scx, scy, scz,
        )

    def _bias_lag(self, dnz: float, dnz_lp: float, hn: float, since: float) -> tuple[bool, float]:
        """Whether the stages' heading difference ``dnz`` (rad, beyond ±_HEAD_ERR_MAX; ``dnz_lp`` its low-pass over
        tau_ncf_s) is a gyro bias's lag, which the heading rows must learn from the NCF's heading error ``hn`` (rad);
        and the steadiness timer's new start (``since``: the state's ``lag_since_s``).

        A bias ``b`` along world up makes the blend lag the field by ``b tm`` (``tm``: tau_mag_s over the field's
        weight) and the NCF by ``b tau_ncf_s``: a steady difference ``b (tm - tau_ncf_s)``, 17° for 1.4 °/s. Held to
        ±_HEAD_ERR_MAX, the rows learnt such a bias only if they caught it while the difference grew (in level turns
        after a start without rest, up to ~1 °/s); beyond, heading lagged by up to ``b tm`` for minutes. Taken for
        one (on a sample whose ``hn`` is within ±_HEAD_ERR_MAX, as a bias within BIAS_GATE_SIGMAS of the prior keeps
        it) while within what BIAS_GATE_SIGMAS of the prior can hold, and once it has stayed within ``tol`` of its
        low-pass for ``tm`` on every magnetometer sample used (a rejected field leaves both as they were; the rows
        then wait for its steadiness anyway). A start's, a heading set's or a new field's difference decays at
        ``tm``, which the low-pass lags by ``dnz tau_ncf_s / (tm - tau_ncf_s)``: ``tol`` is that lag at
        ±_HEAD_ERR_MAX, so no decay beyond it is taken; the peak where it turns from growing to decaying does not
        stay put for ``tm``, nor does the difference a field that turns as the sensor moves through it opens.
        """
        p = self.params
        t_ncf = p.tau_ncf_s
        tm = p.tau_mag_s / self._mag_weight
        span = tm - t_ncf
        lim = BIAS_GATE_SIGMAS * p.bias_sigma_init_rad_s * span
        # (span > 0: a blend no slower than the NCF opens no such difference, and lim > ±_HEAD_ERR_MAX then.)
        if span > 0.0 and dnz * dnz < lim * lim:
            tol = _HEAD_ERR_MAX * t_ncf / span
            e = dnz - dnz_lp
            if e * e < tol * tol:
                t = self._t_last
                if since == _INF:
                    since = t
                # (A single noisy hn beyond ±_HEAD_ERR_MAX is left out, not taken as the lag's end.)
                return t - since >= tm and hn * hn < _HEAD_ERR_MAX2, since
        return False, _INF

    def _end_lag(self) -> None:
        """End the steadiness timer of :meth:`_bias_lag` (the attitude or the field's reference was changed from
        outside the stages' own dynamics)."""
        x = self._x
        if x[_I_LAG] != _INF:
            self._x = (*x[:_I_LAG], _INF, *x[_I_LAG + 1:])

    def _gyro_clipped(self, var_clip: float) -> None:
        """A gyro sample at its range: the attitude may be off by up to the range times the step (rad, squared:
        ``var_clip``). Restart the accelerometer's and magnetometer's blends and the gravity low-pass as running
        means from the next sample on, as at start-up (no bias learnt meanwhile in 9-D; in 6-D only from a tilt error
        a bias could hold), so that they bring the attitude back fast; x-io Fusion's angular-rate recovery does the
        same with a fixed gain."""
        self.n_gyro_clipped += 1
        self._n_init = 1
        self._end_lag()
        self._var_incl += var_clip
        self._var_head += var_clip

    def _end_rest(self) -> None:
        """Motion again. (Whether the bias counts as seen is decided in :meth:`_rest_agrees`, once the estimate
        converged on a rest: a rest too short for that must not lock a half-learnt offset in.)"""
        self.at_rest = False

    def _rest_agrees(self, ex: float, ey: float, ez: float) -> bool:
        """Whether a steady gyro (low-passed minus the bias estimate: ``ex, ey, ez``, rad/s) may be taken for rest.

        A bias does not jump; a rotation does begin. Before the bias was first seen at rest any steady rate within
        ``bias_max_rad_s`` is a bias (a consumer MEMS gyro's offset can be 10°/s); afterwards a steady rate beyond
        what the estimate's uncertainty and a bias's instability between rests (:data:`REST_BIAS_TOL_RAD_S`)
        explain is a slow turn (a tracked robot turning in place), unless it lasts :data:`REST_RELEARN_S`.
        """
        if self.still_hint:
            return True  # odometry says the robot stands still: a steady rate is the bias, whatever it was
        e2 = ex * ex + ey * ey + ez * ez
        # (Its common case, the last line, is written out in _step: they change together.)
        if not self._bias_rested:
            # The first rest: once the estimate has converged on it (within the tolerance, two time constants in),
            # it was seen.
            p = self.params
            if e2 < _REST_TOL2 and self._rest_s >= p.rest_min_s + 2.0 * p.rest_tau_s:
                self._bias_rested = True
                bx, by, bz = self._x[_I_BIAS:_I_BIAS + 3]
                if bx * bx + by * by + bz * bz > 9.0 * p.bias_sigma_init_rad_s**2:
                    # An offset far beyond the prior (a consumer MEMS gyro): the attitude's blends have averaged
                    # samples carried by the wrong rate since the start. Start them again, now that the rate is right.
                    # The reference field's dip was measured through that attitude too.
                    self._n_init = 1
                    self._forget_mag_reference()
            return True
        p00, _, _, p11, _, p22 = self._kf.p
        return e2 < _REST_TOL2 + 9.0 * (p00 + p11 + p22) or self._rest_s >= REST_RELEARN_S

    @property
    def state(self) -> CcfState:
        """The per-sample state, named (a copy; for inspection and tests, not the hot path)."""
        return CcfState._make(self._x)

    @property
    def gyro_bias(self) -> tuple[float, float, float]:
        """Gyroscope bias estimate, rad/s, body frame."""
        b = self._x
        return (b[_I_BIAS], b[_I_BIAS + 1], b[_I_BIAS + 2])

    @property
    def gyro_bias_sigma_rad_s(self) -> float:
        """1-σ uncertainty of :attr:`gyro_bias`, rad/s, the RMS over the axes of the NCF's covariance:
        ``bias_sigma_init_rad_s`` while nothing is known, ``bias_sigma_rest_rad_s`` after a rest, shrinking as the
        NCF learns and growing back with ``bias_walk_rad_s_sqrt_s`` (it scales the reported drift variance)."""
        return self.params.bias_sigma_init_rad_s * sqrt(self._kf.u)

    @property
    def ncf_quaternion(self) -> Quat:
        """The NCF stage's own attitude ``exp(dn) ⊗ q`` (internal ENU frame), ``(w, x, y, z)``."""
        qw, qx, qy, qz = self._q
        dx, dy, dz = (0.5 * v for v in self._x[_I_DN:_I_DN + 3])
        # (1, dx, dy, dz) ⊗ q, normalised: first order in the small world-frame rotation dn.
        w = qw - dx * qx - dy * qy - dz * qz
        x = qx + dx * qw + dy * qz - dz * qy
        y = qy - dx * qz + dy * qw + dz * qx
        z = qz + dx * qy - dy * qx + dz * qw
        n = 1.0 / sqrt(w * w + x * x + y * y + z * z)
        return (w * n, x * n, y * n, z * n)

    @property
    def orientation_variance(self) -> tuple[float, float, float]:
        """Variance of roll, pitch, yaw errors, rad² (yaw relative to the start without a magnetometer)."""
        vi = self._incl_var + self._var_incl
        vh = self._var_head + (self._head_var if self._heading_known else 0.0)
        if self._head_lag_tau2 and self._heading_known:
            vh += self._heading_lag_var()
        return (vi, vi, vh)

    def _heading_lag_var(self) -> float:
        """Variance (rad²) of the heading blend's lag behind the bias error along world up (without the heading rows)."""
        qw, qx, qy, qz = self._q
        # World up in body coordinates: the body->world matrix's third row.
        var_up = self._kf.variance_along(
            2.0 * (qx * qz - qw * qy), 2.0 * (qy * qz + qw * qx), 1.0 - 2.0 * (qx * qx + qy * qy))
        # A field that wanders is blended with its weight w (< 1): the blend's time constant is tau_mag_s / w. A
        # rejected field's weight can be smaller, but then it is not blended: the lag is what its last use left.
        w = self._mag_weight
        if w < _W_BLENDED_MIN:
            w = _W_BLENDED_MIN
        return self._head_lag_tau2 * var_up / (w * w)

    def estimate(self) -> tuple[Quat, tuple[float, float, float], tuple[float, float, float]]:
        """:attr:`quaternion`, :attr:`orientation_variance` and :attr:`gyro_bias` in one call (the three properties'
        steps written out: the engine reads them after every sample; they change together, tested)."""
        x = self._x
        vi = self._incl_var + self._var_incl
        vh = self._var_head + (self._head_var if self._heading_known else 0.0)
        if self._head_lag_tau2 and self._heading_known:
            vh += self._heading_lag_var()
        return (self._q if self._identity_frame else quat_mul_scalar(self._frame, self._q), (vi, vi, vh),
                (x[_I_BIAS], x[_I_BIAS + 1], x[_I_BIAS + 2]))

    def set_gyro_bias(self, bias_rad_s: tuple[float, float, float], sigma_rad_s: float) -> bool:
        """Set the bias state (rad/s, body) and its covariance to ``diag(sigma_rad_s²)`` (rad/s): the NCF refines it
        from there as from a rest of that quality. The orientation is kept."""
        bx, by, bz = (float(v) for v in bias_rad_s)
        p = float(sigma_rad_s) ** 2
        self._x = tuple(CcfState._make(self._x)._replace(bias_x=bx, bias_y=by, bias_z=bz))
        if not self.initialized:
            self._gyro_lp = (bx, by, bz)  # the rest low-pass starts from it (as _init does from the bias)
        self._kf.set_prior(p, p / self.params.bias_sigma_init_rad_s**2)
        # A prior only: a consumer MEMS gyro's turn-on bias moves by up to ~1°/s between runs, so the next rest
        # learns it afresh (see _rest_agrees).
        return True

    def magnetometer_changed(self, change_rel: float | None = None) -> None:
        """The magnetometer's calibration changed (online hard iron applied; ``change_rel``: how far off the samples
        before it may have been, over the field norm, None if not known): the disturbance gate's reference field is
        learnt anew from the next samples instead of rejecting the corrected field for ``mag_reaccept_s``; the
        consistency check keeps the part of the field's wander that the change cannot explain
        (:meth:`_mag_calibration_changed`)."""
        if self.initialized:
            # (Heading follows over tau_mag_s: snapping it to the first applied offsets, which are refined for a
            # while, measured worse.)
            self._mag_calibration_changed(change_rel)
            self._end_lag()

    def _rotate_about_up(self, angle_rad: float) -> None:
        """:meth:`OrientationFilter.set_heading`'s turn: the LCF orientation and the NCF offset ``dn`` (world frame)
        turn together, so the cascade sees no step (body-frame state: bias, filtered gravity, unchanged); so do the
        magnetometer gate's world-frame filters and this block's field sum, so that the field does not look as if it
        moved."""
        super()._rotate_about_up(angle_rad)
        c, s = math.cos(angle_rad), math.sin(angle_rad)
        x = CcfState._make(self._x)
        (dn_e, dn_n), (field_e, field_n) = about_up(c, s, x.dn_e, x.dn_n), about_up(c, s, x.field_e, x.field_n)
        self._x = tuple(x._replace(dn_e=dn_e, dn_n=dn_n, field_e=field_e, field_n=field_n, lag_since_s=_INF))
        self._turn_mag_about_up(c, s)
