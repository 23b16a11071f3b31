"""Discretisation: the per-sample and per-block constants of :class:`~ccf_ros.core.ccf.QuaternionCcf` for a time span,
computed once per 0.1 % bin of spans and cached, and the exact step of the second-order gravity low-pass."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

from .params import BIAS_GATE_SIGMAS, CLIP_FRACTION, MAG_BAND_S, MAG_SCORE_S, CcfParams


def butterworth_step(tau_s: float, dt: float) -> tuple[float, float, float, float]:
    """Exact one-step transition ``(p11, p12, p21, p22)`` of the second-order Butterworth low-pass of group delay
    ``tau_s`` (s) over ``dt`` (s), for the state (value, rate) with the input held over the step::

        value' = p11 value + p12 rate + (1 - p11) input,   rate' = p21 (value - input) + p22 rate
    """
    wn = math.sqrt(2.0) / tau_s  # group delay at DC 2 zeta / wn with zeta = 1/sqrt(2)
    sg = wn / math.sqrt(2.0)  # zeta wn; the damped frequency equals it for zeta = 1/sqrt(2)
    e = math.exp(-sg * dt)
    c, s = math.cos(sg * dt), math.sin(sg * dt)
    return e * (c + s), e * s / sg, -e * wn * wn * s / sg, e * (c - s)


@dataclass(frozen=True, slots=True)
class _Coefficients:
    """Per-sample constants derived from :class:`CcfParams` for sample periods in ``[dt_lo, dt_hi]`` (s), computed at
    the bin's middle (see :meth:`of`)."""

    dt_lo: float
    dt_hi: float
    k_acc: float
    k_mag: float
    k_lp: float
    k_min: float
    k_ncf: float
    lp_a: float
    lp12: float
    lp21: float
    lp22: float
    k_rest: float
    rest_gyro2: float
    rest_acc2: float
    bias_max: float
    bias_max2: float
    rest_min_s: float
    rest_bias: bool
    keep_incl: float
    keep_head: float
    r_head: float
    k_band1: float
    k_band2: float
    k_score: float
    sigma_init: float
    var_arw: float
    clip: float
    var_clip: float

    @classmethod
    def of(cls, p: CcfParams, key: int, own_clip: bool = True) -> _Coefficients:
        """The coefficients of bin ``key`` of sample periods (:func:`_bin`); ``own_clip`` False: no threshold of the
        filter's own for ``gyro_range_rad_s`` (its caller checks the raw readings: ``raw_clip_check``)."""
        dt_lo, dt, dt_hi = _bin_range(key)
        k_rest = -math.expm1(-dt / p.rest_tau_s)
        # Rest thresholds apply to (sample - new low-pass) = (1 - k_rest) * (sample - old low-pass).
        rest_keep2 = (1.0 - k_rest) ** 2 if k_rest < 1.0 else 1e-300
        lp = butterworth_step(p.tau_acc_lp_s, dt)
        # The start-up hands the blends over to their time constants, and it lasts until the slowest would, heading's
        # included: without a magnetometer too, where it is the longest the bias waits for a tilt error a bias
        # could hold (QuaternionCcf._step, step 3).
        taus = (p.tau_acc_s, p.tau_acc_lp_s, p.tau_mag_s)
        return cls(
            dt_lo=dt_lo,
            dt_hi=dt_hi,
            k_acc=-math.expm1(-dt / p.tau_acc_s),
            k_mag=-math.expm1(-dt / p.tau_mag_s),
            # The low-pass's start-up running mean hands over at the rate of a first-order filter of its delay.
            k_lp=-math.expm1(-dt / p.tau_acc_lp_s),
            k_min=-math.expm1(-dt / max(taus)),
            k_ncf=-math.expm1(-dt / p.tau_ncf_s),
            lp_a=1.0 - lp[0],
            lp12=lp[1],
            lp21=lp[2],
            lp22=lp[3],
            k_rest=k_rest,
            rest_gyro2=p.rest_gyro_rad_s**2 / rest_keep2,
            rest_acc2=p.rest_acc_m_s2**2,
            bias_max=p.bias_max_rad_s,
            bias_max2=p.bias_max_rad_s**2,
            rest_min_s=p.rest_min_s,
            rest_bias=p.rest_bias,
            # Drift variances decay with the blends' (combined) time constants once corrected again.
            keep_incl=math.exp(-2.0 * dt / (p.tau_acc_s + p.tau_acc_lp_s)),
            keep_head=math.exp(-2.0 * dt / p.tau_mag_s),
            # A field sample's heading variance for the re-acquisition gain, rad²: heading_sigma² once per tau_mag_s
            # (its errors are the field's, correlated over the blend's memory, not per sample).
            r_head=p.heading_sigma_rad**2 * p.tau_mag_s / dt,
            k_band1=-math.expm1(-dt / MAG_BAND_S[0]),
            k_band2=-math.expm1(-dt / MAG_BAND_S[1]),
            k_score=-math.expm1(-dt / MAG_SCORE_S),
            sigma_init=p.bias_sigma_init_rad_s,
            var_arw=p.gyro_arw_rad_sqrt_s**2 * dt,
            # (A float compare against inf is all a gyro without a known range costs.)
            clip=CLIP_FRACTION * p.gyro_range_rad_s if p.gyro_range_rad_s > 0.0 and own_clip else math.inf,
            var_clip=(p.gyro_range_rad_s * dt) ** 2,
        )


@dataclass(frozen=True, slots=True)
class _BlockCoefficients:
    """Constants of one NCF bias update for block spans in ``[t_lo, t_hi]`` (s), computed at the bin's middle (see
    :meth:`~ccf_ros.core.ccf.bias.BiasKalman.update`)."""

    t_lo: float
    t_hi: float
    m_a: float
    m12: float
    m21: float
    m22: float
    k_ncf: float
    inv_tau_ncf: float
    r_tilt: float
    inv_rot2: float
    walk: float
    p_init: float
    p_rest: float
    keep_rest: float
    gate_tilt: float
    gate_head: float
    gate_p: float
    start_tilt2: float
    k_band1: float
    k_band2: float
    k_score: float
    wander_var: float
    drift_var: float
    drift_step: float
    drift_curve_var: float
    motion_bias: bool
    bias_from_mag: bool

    @classmethod
    def of(cls, p: CcfParams, key: int) -> _BlockCoefficients:
        """The constants of bin ``key`` of block spans (:func:`_bin`)."""
        t_lo, t, t_hi = _bin_range(key)
        m = butterworth_step(p.tau_acc_lp_s, t)
        w = p.bias_walk_rad_s_sqrt_s
        return cls(
            t_lo=t_lo,
            t_hi=t_hi,
            m_a=1.0 - m[0],
            m12=m[1],
            m21=m[2],
            m22=m[3],
            k_ncf=-math.expm1(-t / p.tau_ncf_s),
            inv_tau_ncf=1.0 / p.tau_ncf_s,
            # Variance of one block's tilt observation, (rad/s)²: the noise density (walk tau_bias)² over the block.
            r_tilt=(w * p.tau_bias_s) ** 2 / t,
            inv_rot2=1.0 / p.bias_rotation_rad_s**2,
            walk=w * w * t,
            p_init=p.bias_sigma_init_rad_s**2,
            p_rest=p.bias_sigma_rest_rad_s**2,
            keep_rest=math.exp(-t / p.rest_tau_s),
            # The gate's floors, (rad/s)²: the rate at which the attitude references' own errors would show as drift
            # through the NCF.
            gate_tilt=(p.incl_sigma_rad / p.tau_ncf_s) ** 2,
            gate_head=(p.heading_sigma_rad / p.tau_ncf_s) ** 2,
            # The gate holds once the bias's variance along the observation is below a quarter of the initial one.
            gate_p=0.25 * p.bias_sigma_init_rad_s**2,
            # Within the start-up, once the tilt is found, a 6-D filter's bias learns only while the NCF's tilt error
            # (rad, squared) is one a bias could hold: the gate's 3 sigma of the prior times tau_ncf_s (the
            # proportional NCF lags a constant bias b by b tau_ncf_s) and of the accelerometer's own error
            # (incl_sigma_rad). 9-D waits for the whole start-up (0: never), its heading being a running mean of the
            # field through the bias.
            start_tilt2=(
                0.0
                if p.use_mag
                else BIAS_GATE_SIGMAS**2 * ((p.bias_sigma_init_rad_s * p.tau_ncf_s) ** 2 + p.incl_sigma_rad**2)
            ),
            k_band1=-math.expm1(-t / MAG_BAND_S[0]),
            k_band2=-math.expm1(-t / MAG_BAND_S[1]),
            k_score=-math.expm1(-t / MAG_SCORE_S),
            # Hysteresis: inconsistent above the threshold, consistent again below half of it (squared, unit vectors'
            # chord ~ angle); a zero threshold switches the check off.
            # The band-passed wander of a homogeneous field's direction seen through a moving attitude (half the
            # threshold, squared; inf: the check is off) ...
            wander_var=(0.5 * p.mag_consistency_rad) ** 2 if p.mag_consistency_rad > 0.0 else math.inf,
            # ... plus the attitude's drift from a bias error of bias_sigma_init over the band-pass's long time
            # constant (a ramp of rate r shows as r * MAG_BAND_S[1]), scaled by the bias's relative variance (the
            # new-field candidate's check) ...
            drift_var=(2.0 * p.bias_sigma_init_rad_s * MAG_BAND_S[1]) ** 2,
            # ... or that drift as the band shows it: a ramp of 2 bias_sigma_init (rad/s, times the bias's relative
            # standard deviation) band-passed as the field's direction is, rad per block.
            drift_step=2.0 * p.bias_sigma_init_rad_s * t,
            # ... or, for the band's curvature, from a bias error of that size learnt: a step of rate r shows at
            # most as r * MAG_BAND_S[1] / e (t exp(-t / MAG_BAND_S[1]) at t = MAG_BAND_S[1]); a steady rate not at all.
            drift_curve_var=(2.0 * p.bias_sigma_init_rad_s * MAG_BAND_S[1] / math.e) ** 2,
            motion_bias=p.motion_bias,
            bias_from_mag=p.bias_from_mag,
        )


def _bin(dt: float) -> int:
    """The 0.1 % bin of time spans (s, > 0: a sample period, a bias-update block) that holds ``dt``.

    Stamps jitter: float stamps near 1.7e9 s resolve 0.24 µs (dt wobbles by ~1e-4 relative), a driver that stamps on
    arrival by far more. Gains are taken at the bin's middle (a 0.05 % change of a blend gain is immaterial; the
    integration uses the exact dt), so a stream costs as many computations of them as it visits bins, not one per
    sample or block.
    """
    return round(math.log(dt) * 1000.0)


def _bin_range(key: int) -> tuple[float, float, float]:
    """Lower edge, middle and upper edge of bin ``key`` (:func:`_bin`), s."""
    return math.exp((key - 0.5) / 1000.0), math.exp(key / 1000.0), math.exp((key + 0.5) / 1000.0)


_C = TypeVar('_C')


def _cached(cache: dict[int, _C], span_s: float, make: Callable[[int], _C]) -> _C:
    """``make(bin)`` for the bin of ``span_s`` (s), from ``cache`` (kept to 256 bins: jitter or rate changes without
    end must not grow it)."""
    key = _bin(span_s)
    c = cache.get(key)
    if c is None:
        if len(cache) >= 256:
            cache.clear()
        c = cache[key] = make(key)
    return c
