"""The magnetometer disturbance gate of :class:`~ccf_ros.core.ccf.QuaternionCcf`: whether a magnetometer sample may
steer heading. Norm and dip are compared with a reference field (learnt after a (re)initialisation, replaced by a new
field that stays steady while the body turns); the field's direction in the world is checked to stay put (a field
that moves with position or with the body is no heading reference). The per-sample bounds test is inlined in
``QuaternionCcf._step``; everything here runs on rejected samples or once per bias-update block."""

from __future__ import annotations

import math
from math import sqrt

from ..base import OrientationFilter
from .bias import BiasKalman
from .discretisation import _BlockCoefficients, _Coefficients
from .params import MAG_BAND_S, MAG_REJECT_SIGMAS, NEW_FIELD_TURN_RAD, CcfParams

#: The new-field timer loses this many seconds per second of samples that disagree with the candidate.
_LEAK = 3.0
#: ... and so does the steadiness timer (QuaternionCcf._step adds each sample's time back with its block's).
STEADY_LOSS = 1.0 + _LEAK
_REJECT2 = MAG_REJECT_SIGMAS**2


def _turned(
    ce: float, cn: float, cu: float, ae: float, an: float, au: float, be: float, bn: float, bu: float, fe: float,
    fn: float, fu: float,
) -> tuple[float, float, float, float, float, float, float, float, float]:
    """The three (east, north, up) vectors ``a``, ``b`` and ``f`` each turned by the rotation vector ``(ce, cn, cu)``
    (rad; Rodrigues' formula). Written out per vector: a loop over them, building a list, cost as much as the turns
    (once per bias block, in the consistency check)."""
    t2 = ce * ce + cn * cn + cu * cu
    if t2 < 1e-8:
        # sin(t)/t and (1 - cos(t))/t² to well below 1e-16 for |t| < 1e-4.
        s, k = 1.0 - t2 / 6.0, 0.5 - t2 / 24.0
    else:
        t = sqrt(t2)
        s, k = math.sin(t) / t, (1.0 - math.cos(t)) / t2
    # v + s (c x v) + k c x (c x v) for v = a, b, f; p, q, r = c x a, c x b, c x f.
    pa, pb, pc = cn * au - cu * an, cu * ae - ce * au, ce * an - cn * ae
    qa, qb, qc = cn * bu - cu * bn, cu * be - ce * bu, ce * bn - cn * be
    ra, rb, rc = cn * fu - cu * fn, cu * fe - ce * fu, ce * fn - cn * fe
    return (
        ae + s * pa + k * (cn * pc - cu * pb),
        an + s * pb + k * (cu * pa - ce * pc),
        au + s * pc + k * (ce * pb - cn * pa),
        be + s * qa + k * (cn * qc - cu * qb),
        bn + s * qb + k * (cu * qa - ce * qc),
        bu + s * qc + k * (ce * qb - cn * qa),
        fe + s * ra + k * (cn * rc - cu * rb),
        fn + s * rb + k * (cu * ra - ce * rc),
        fu + s * rc + k * (ce * rb - cn * ra),
    )


def about_up(c: float, s: float, e: float, n: float) -> tuple[float, float]:
    """``(e, n)`` (east, north) turned about world up by the angle of cosine ``c`` and sine ``s``."""
    return c * e - s * n, s * e + c * n


def _band_about_up(c: float, s: float, band: tuple[float, ...]) -> tuple[float, float, float, float, float, float, float]:
    """A band's state (its two unit-vector low-passes, east, north, up each, and its score) turned about world up by
    the angle of cosine ``c`` and sine ``s``."""
    ae, an, au, be, bn, bu, s2 = band
    return (*about_up(c, s, ae, an), au, *about_up(c, s, be, bn), bu, s2)


class MagGate(OrientationFilter):
    """The gate's state and rare paths (a base of :class:`~ccf_ros.core.ccf.QuaternionCcf`, which owns the
    coefficients, the bias filter and the heading variance it reads)."""

    __slots__ = (
        '_mag_band',
        '_mag_band_t',
        '_mag_bounds',
        '_mag_candidate',
        '_mag_consistent',
        '_mag_curve',
        '_mag_drift',
        '_mag_have_ref',
        '_mag_learn_n',
        '_mag_learn_s',
        '_mag_learn_tilt',
        '_mag_new_s',
        '_mag_recheck',
        '_mag_ref',
        '_mag_rej_n2',
        '_mag_rej_t',
        '_mag_rejected_t',
        '_mag_steady_s',
        '_mag_u',
        '_mag_weight',
        # The heading's drift variance, rad² (the filter's; raised here when a new field is accepted).
        '_var_head',
    )
    params: CcfParams
    # Owned by QuaternionCcf (declared there), read here.
    _coef: _Coefficients
    _bcoef: _BlockCoefficients
    _kf: BiasKalman
    _var_head: float
    _n_init: int

    def _forget_mag_reference(self) -> None:
        """No reference field: the next usable magnetometer sample becomes it (see :meth:`_mag_rejected`); nor any
        memory of the field's motion."""
        self._forget_mag_field()
        self._forget_mag_wander()

    def _forget_mag_field(self) -> None:
        """The reference field and the steadiness timer forgotten (the consistency check's memory is kept)."""
        self._mag_ref = (0.0, 0.0)
        # Bounds that accept nothing, so that the first sample goes through _mag_rejected and sets the reference.
        self._mag_bounds = (math.inf, -math.inf, 2.0, -2.0)
        self._mag_candidate = (0.0, 0.0, 0.0, 0.0, (0.0,) * 7)
        self._mag_have_ref = False
        self._mag_new_s = 0.0
        self._mag_rejected_t = -math.inf
        self._mag_learn_s = 0.0
        self._mag_learn_n = 0
        # The LCF's tilt corrections (east, north, rad) summed while the reference is learnt (QuaternionCcf._step, per
        # block), and its second measurement after a start-up (None: none; (): due at the start-up's end; see
        # _mag_recheck_begin).
        self._mag_learn_tilt = (0.0, 0.0)
        self._mag_recheck: tuple[float, ...] | None = None
        self.mag_disturbed = False
        # A leaky timer of how long the field has steered heading, s: + the time of each block, - STEADY_LOSS x the
        # time between two magnetometer samples both rejected, within [0, MAG_BAND_S[1]]. Below the top, the field has
        # not shown long enough that it stays put for its heading error to teach the bias or re-acquire heading at
        # once (see QuaternionCcf._step). And the stamp (s) and squared norm (sensor unit²) of the last rejected sample.
        self._mag_steady_s = 0.0
        self._mag_rej_t = -math.inf
        self._mag_rej_n2 = -1.0

    def _forget_mag_wander(self) -> None:
        """The consistency check's memory of the field's motion forgotten: its filters, scores and verdict."""
        # The field's world direction band-passed (two unit-vector low-passes and the squared deviation's low-pass;
        # None: seeded by the next block), and the verdict.
        self._mag_band: tuple[float, ...] | None = None
        self._mag_band_t = -math.inf
        # The band's ramp-free part: a third low-pass f (of the second, MAG_BAND_S[1]) and the squared deviation's
        # low-pass of (a - b) - (b - f), which is zero for a direction that turns at a constant rate (seeded with the
        # band).
        self._mag_curve: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)
        self._mag_consistent = True
        # The drift an unknown bias may have given the attitude (a ramp of 2 bias_sigma_init sqrt(u), u the bias's
        # relative variance at the time) through the band's two low-passes: (ramp - first, first - second), rad.
        # The second is what the band shows of it.
        self._mag_drift = (0.0, 0.0)
        # The bias's relative uncertainty the curvature's verdict allows for: the largest over the band's memory.
        self._mag_u = 0.0
        # The heading blend's gain relative to tau_mag_s's (1: the field is as steady as a homogeneous one).
        self._mag_weight = 1.0

    def _mag_calibration_changed(self, change_rel: float | None) -> None:
        """The magnetometer's calibration changed; the samples before it may have been off by ``change_rel`` of the
        field norm (None: unknown, all is forgotten). The reference field is learnt anew, and the consistency check's
        direction filters start again (the field's direction jumps with the offset), but its wander scores keep the
        part that the change cannot explain.

        An offset error of ``e`` (share of the norm) turning with the body moves the field's direction by up to
        ``asin(e)`` (``e`` rad for a small one). ``e² / 2`` (a sinusoidal wobble of amplitude ``e``) is taken off
        both scores, and the verdict is taken again from the rest. That is a typical share of the wander such an
        error causes, not the largest: a turn about the vertical at 60° dip gives ~0.7 e² through the band-pass.
        A field that wandered by more stays rejected: one that varies with position, which a first offset fitted
        over a few seconds of the path may partly follow. The wander that the offset caused mostly goes with it, and
        the rest decays with the score. On a plateau: 0.17-0.6 e² give the same BROAD and dipole figures; 0.1 e²
        keeps BROAD 33's corrected field out (heading 1.55 -> 1.66°), 0.75 e² lets a dipole's field back in (0.29 ->
        0.77° at 286 Hz; doc/history/2026-12-07-session24.md). (Before, every jump of the offset reset the check,
        and such a field was accepted again after each.)"""
        self._forget_mag_field()
        band = self._mag_band
        if change_rel is None or band is None:
            self._forget_mag_wander()
            return
        e2 = 0.5 * change_rel * change_rel
        s2 = band[6] - e2 if band[6] > e2 else 0.0
        curve = self._mag_curve
        s2c = curve[3] - e2 if curve[3] > e2 else 0.0
        # (The filters are seeded again from the next block: a gap, as after a rejection, keeps the scores.)
        self._mag_band = (*band[:6], s2)
        self._mag_band_t = -math.inf
        self._mag_curve = (*curve[:3], s2c)
        self._mag_judge(s2, s2c, self._mag_drift[1], self._mag_u)

    def _turn_mag_about_up(self, c: float, s: float) -> None:
        """The gate's world-frame state turned about up by the angle of cosine ``c`` and sine ``s`` (the attitude is
        turned so: a heading set), so that the field seen through the attitude does not look as if it moved."""
        if self._mag_band is not None:
            self._mag_band = _band_about_up(c, s, self._mag_band)
        fe, fn, fu, s2c = self._mag_curve
        self._mag_curve = (*about_up(c, s, fe, fn), fu, s2c)
        cn, cs, n, turn, band = self._mag_candidate
        self._mag_candidate = (cn, cs, n, turn, _band_about_up(c, s, band))

    def _bounds(self, norm: float, sin_dip: float) -> tuple[float, float, float, float]:
        """Acceptance bounds (squared norm, sin(dip)) around a field of ``norm`` and dip ``asin(sin_dip)``.

        Comparing squared norms and sines keeps sqrt and asin out of the per-sample path.
        """
        p = self.params
        dip = math.asin(max(-1.0, min(1.0, sin_dip)))
        lo = norm * (1.0 - p.mag_norm_tol)
        hi = norm * (1.0 + p.mag_norm_tol)
        return (
            lo * lo,
            hi * hi,
            math.sin(max(-math.pi / 2, dip - p.mag_dip_tol_rad)),
            math.sin(min(math.pi / 2, dip + p.mag_dip_tol_rad)),
        )

    def _set_mag_reference(self, norm: float, sin_dip: float, *, learn: bool = True) -> None:
        """Accept a field of ``norm`` (sensor unit) and dip ``asin(sin_dip)`` as undisturbed; with ``learn``, as the
        first sample of the mean over the next ``mag_ref_learn_s`` that becomes the reference."""
        self._mag_ref = (norm, sin_dip)
        self._mag_have_ref = True
        self._mag_new_s = 0.0
        self.mag_disturbed = False
        self._mag_learn_n = 1
        self._mag_learn_s = self.params.mag_ref_learn_s if learn else 0.0
        self._mag_learn_tilt = (0.0, 0.0)
        self._mag_recheck = None
        if self._mag_learn_s > 0.0:
            # Learning: the reference is the mean of the samples of the next mag_ref_learn_s, all accepted; bounds
            # that accept nothing route them through _mag_rejected, off the common path.
            self._mag_bounds = (math.inf, -math.inf, 2.0, -2.0)
        else:
            self._mag_bounds = self._bounds(norm, sin_dip)
        self._mag_candidate = (0.0, 0.0, 0.0, 0.0, (0.0,) * 7)

    def _mag_recheck_begin(self) -> None:
        """The start-up has ended, and the reference was learnt during it while the tilt still converged (see
        _mag_rejected): the field is measured again over ``mag_ref_learn_s``, now through the converged tilt. The
        reference's bounds still decide meanwhile (all samples pass _mag_rejected, through bounds that accept nothing,
        off the common path, as while it was learnt)."""
        # (its bounds, time left, samples, their norms summed, samples within the norm bounds, their sin(dip) summed,
        # samples within the bounds)
        self._mag_recheck = (*self._mag_bounds, self.params.mag_ref_learn_s, 0.0, 0.0, 0.0, 0.0, 0.0)
        self._mag_bounds = (math.inf, -math.inf, 2.0, -2.0)

    def _mag_recheck_sample(self, recheck: tuple[float, ...], dt: float, norm: float, sin_dip: float) -> bool:
        """One sample of the reference's second measurement (see _mag_recheck_begin); whether the reference's
        bounds accept it."""
        lo2, hi2, lo_dip, hi_dip, left, n, sn, n_in, ss, n_ok = recheck
        n2 = norm * norm
        n += 1.0
        sn += norm
        in_norm = lo2 <= n2 <= hi2
        ok = False
        if in_norm:
            n_in += 1.0
            ss += sin_dip
            if lo_dip <= sin_dip <= hi_dip:
                ok = True
                n_ok += 1.0
        left -= dt
        if left > 0.0:
            self._mag_recheck = (lo2, hi2, lo_dip, hi_dip, left, n, sn, n_in, ss, n_ok)
        else:
            self._mag_recheck = None
            self._mag_bounds = (lo2, hi2, lo_dip, hi_dip)
            self._mag_recheck_end(n, sn, n_in, ss, n_ok)
        return ok

    def _mag_recheck_end(self, n: float, sn: float, n_in: float, ss: float, n_ok: float) -> None:
        """The second measurement's verdict (``n`` samples, their norms summed ``sn``; ``n_in`` of them within the
        reference's norm bounds, their sin(dip) summed ``ss``; ``n_ok`` within its dip bounds too).

        The norm does not depend on the tilt, the dip does: a field of the reference's norm (its mean within
        ``mag_norm_tol``) is the same field, its dip now seen through the converged tilt, and becomes the reference
        (the mean dip of the samples within the norm bounds). If the old reference kept most of it out, the heading
        since has been the gyro's (and the start-up's running mean was cut short where that began): it is handed over
        as a new field is, heading re-acquired from it, its steadiness taken as shown while the consistency check
        finds it put. Else the reference is only refined. Another norm: a field other than the start's (the start's
        was a disturbance, or the sensor has moved into another), left to the new-field path as before."""
        p = self.params
        rn = self._mag_ref[0]
        if not n_in or abs(sn / n - rn) > p.mag_norm_tol * rn:
            return
        self._set_mag_reference(rn, ss / n_in, learn=False)
        if n_ok < 0.5 * n and self._mag_consistent:
            self._mag_steady_s = MAG_BAND_S[1]
            self._var_head = max(self._var_head, (0.5 * math.pi) ** 2)

    def _mag_consistency(self, we: float, wn: float, wu: float, ce: float, cn: float, cu: float) -> None:
        """Whether the field stays put in the world, once per block of ``t`` s: its samples summed in world
        coordinates through the attitude (``we, wn, wu``: east, north, up, sensor unit), and the heading corrections
        the LCF applied meanwhile (``ce, cn, cu``: a rotation vector in world coordinates, rad; they turn the attitude,
        and so the field seen through it).

        A homogeneous field keeps its world direction however the body turns; the attitude carried by the gyro is
        good to about a degree over seconds. A field that varies with position (a structure near the workspace, a
        magnet passed by), one carried by the body (a magnet or motor on it: it turns with the body) or one that
        changes in time moves. The direction's band-pass between ``MAG_BAND_S`` (its deviation RMS over
        ``MAG_SCORE_S``) against ``mag_consistency_rad`` (with hysteresis: half of it to become consistent again)
        decides whether the field may steer heading (and the bias estimate) at all; agreement of norm and dip with
        a reference cannot see a field that turns. The band's curvature (its ramp-free part) is judged beside it,
        its allowance for the bias only the change of rate while the bias is learnt: an unknown bias turns the
        attitude at a steady rate, a field that varies with position turns it back and forth as the sensor moves
        about.
        """
        c = self._bcoef
        n = sqrt(we * we + wn * wn + wu * wu)
        if not n:
            return
        # The drift an unknown bias gave the attitude, as the band shows it: a ramp at the bias's 2σ band-passed like
        # the field's direction. It builds up over the band's 8 s while the bias stays unknown (a drift needs time
        # to show) and leaves the band as fast as the band forgets once the bias is learnt (after a start while
        # moving the score still holds the start-up's drift: test_started_while_moving_the_heading_converges).
        # Kept across a gap, as the score is. Step for step with the band: a magnetometer that skips blocks stretches
        # the band's time constants and holds the ramp's to the same steps (a stricter check there than in time: at
        # 10 Hz on a 100 Hz IMU the band holds 2.5 blocks' drift per step, the allowance one block's; stepping the
        # ramp by the time since let a wandering field back in at 4 Hz, 2.3 -> 4.5°).
        u = self._kf.u
        xa, xb = self._mag_drift
        xa += c.drift_step * sqrt(u)
        da = c.k_band1 * xa
        xb = (1.0 - c.k_band2) * (xb + da)
        self._mag_drift = (xa - da, xb)
        # The curvature's allowance follows the bias's uncertainty up at once and down only as fast as the band
        # forgets.
        mu = self._mag_u
        mu = self._mag_u = u if u >= mu or self._mag_band is None else mu + c.k_band2 * (u - mu)
        ue, un, uu = we / n, wn / n, wu / n
        band = self._mag_band
        t_now = self._t_last
        gap = t_now - self._mag_band_t > MAG_BAND_S[0]
        self._mag_band_t = t_now
        curve = self._mag_curve
        if band is None or gap:
            # First, or after the field was rejected for a while (the gyro drifted meanwhile): the direction's
            # filters start again from here; the wander scores keep their memory.
            self._mag_band = (ue, un, uu, ue, un, uu, 0.0 if band is None else band[6])
            self._mag_curve = (ue, un, uu, curve[3])
            return
        ae, an, au, be, bn, bu, s2 = band
        fe, fn, fu, s2c = curve
        # The LCF's corrections turned the field seen through the attitude by (ce, cn, cu): turn the filters' states
        # with them, so that only the field's own motion shows. Exactly, not to first order: a heading re-acquired
        # (a new field) turns by up to 180° in one block, and a first-order turn by 0.5 rad leaves the states 2° and
        # 12 % off, which the band then reads as the field's motion for its 8 s.
        ae, an, au, be, bn, bu, fe, fn, fu = _turned(ce, cn, cu, ae, an, au, be, bn, bu, fe, fn, fu)
        k1, k2 = c.k_band1, c.k_band2
        ae += k1 * (ue - ae)
        an += k1 * (un - an)
        au += k1 * (uu - au)
        be += k2 * (ae - be)
        bn += k2 * (an - bn)
        bu += k2 * (au - bu)
        de, dn_, du = ae - be, an - bn, au - bu
        s2 += c.k_score * (de * de + dn_ * dn_ + du * du - s2)
        self._mag_band = (ae, an, au, be, bn, bu, s2)
        fe += k2 * (be - fe)
        fn += k2 * (bn - fn)
        fu += k2 * (bu - fu)
        de, dn_, du = de - (be - fe), dn_ - (bn - fn), du - (bu - fu)
        s2c += c.k_score * (de * de + dn_ * dn_ + du * du - s2c)
        self._mag_curve = (fe, fn, fu, s2c)
        self._mag_judge(s2, s2c, xb, mu)

    def _mag_judge(self, s2: float, s2c: float, xb: float, mu: float) -> None:
        """The verdict from the wander scores ``s2`` (the band's) and ``s2c`` (its curvature's), rad², against their
        allowances (``xb``: the drift an unknown bias shows in the band, rad; ``mu``: the bias's relative variance the
        curvature allows for): the blend's weight and, with hysteresis, whether the field steers heading at all."""
        c = self._bcoef
        # The heading reference is as noisy as the field wanders: the blend's time constant (and the bias estimate's
        # heading noise) grows with the wander beyond a homogeneous field's, which includes the drift an unknown
        # bias gives the attitude.
        r2 = s2 / (c.wander_var + xb * xb)
        # The same from the curvature: a drift at a steady rate leaves none, only the change of rate while the bias
        # is learnt (allowed for in drift_curve_var), so a field that wanders as the sensor moves shows against the
        # homogeneous field's wander alone while the bias is still unknown (after a start while moving), where the
        # band's allowance for its drift lets a field through that turns by tens of degrees.
        r2c = s2c / (c.wander_var + c.drift_curve_var * mu)
        if r2c > r2:
            r2 = r2c
        self._mag_weight = 1.0 / sqrt(r2) if r2 > 1.0 else 1.0
        if self._mag_consistent:
            if r2 > _REJECT2:
                self._mag_consistent = False
        elif r2 < 0.25 * _REJECT2:
            self._mag_consistent = True

    def _mag_rejected(self, dt: float, norm: float, sin_dip: float, me: float, mn: float, mu: float, wx: float,
                      wy: float, wz: float) -> bool:
        """Book-keeping for a magnetometer sample outside the acceptance bounds (rare path).

        Returns True if the sample is to be used after all: it began the reference (first usable sample after a
        (re)initialisation), the reference is being learnt (the ``mag_ref_learn_s`` after that), or a new field
        stayed steady long enough, and put in the world while the body turned by :data:`NEW_FIELD_TURN_RAD`, to
        become the reference. ``me, mn, mu``: the sample in world coordinates (east, north, up) through the attitude;
        ``wx, wy, wz``: the bias-corrected rate, rad/s.
        """
        if not self._mag_have_ref:
            self._set_mag_reference(norm, sin_dip)
            return True
        if self._mag_learn_s > 0.0:
            # Weights growing linearly with the sample's index: after a (re)initialisation while moving, the tilt
            # (and so the dip) converges like 1/t, and the early samples count least.
            i = self._mag_learn_n = self._mag_learn_n + 1
            k = 2.0 / (i + 1)
            rn, rs = self._mag_ref
            self._mag_ref = (rn + k * (norm - rn), rs + k * (sin_dip - rs))
            self._mag_learn_s -= dt
            if self._mag_learn_s <= 0.0:
                self._mag_bounds = self._bounds(*self._mag_ref)
                te, tn = self._mag_learn_tilt
                tol = self.params.mag_dip_tol_rad
                if self._n_init and te * te + tn * tn > tol * tol:
                    # Learnt in a start-up while the LCF turned the tilt by more than the dip the gate tolerates (a
                    # start in strong motion: 13-75° over the 5 s in started_moving_heading.py; at rest or in gentle
                    # motion, the bias's drift: up to 2.3° in field_sweep.py --rest 0.5): its dip was seen through a
                    # tilt still converging (seed 19: -54.6° learnt in a field of -60°). Measured again once the
                    # start-up has ended (_mag_recheck_begin).
                    self._mag_recheck = ()
            return True
        recheck = self._mag_recheck
        if recheck and self._mag_recheck_sample(recheck, dt, norm, sin_dip):
            # (Measured again after a start-up, and within the reference's bounds.)
            return True
        self.mag_disturbed = True
        # The candidate new field: the mean (norm, sin dip) of the rejected samples that agree with it, n of them,
        # and a leaky timer: + dt per agreeing sample, - _LEAK x the time of anything else (an outlier, accepted
        # samples or no magnetometer since the last rejection). A field that agrees for mag_reaccept_s net becomes
        # the reference (with a fraction f of outliers after mag_reaccept_s / (1 - f (1 + _LEAK))); single
        # outliers (noise, a tilt error while moving) do not restart it.
        # n: a float count (0.0: no candidate yet); turn: rad turned while timed; band: the candidate's world
        # direction band-passed as in _mag_consistency (sample by sample here: no heading corrections meanwhile).
        cn, cs, n, turn, band = self._mag_candidate
        p = self.params
        c = self._coef
        t = self._t_last
        timer = self._mag_new_s - _LEAK * (t - self._mag_rejected_t - dt)
        self._mag_rejected_t = t
        if n and abs(norm - cn) <= p.mag_norm_tol * cn and abs(sin_dip - cs) <= p.mag_dip_tol_rad * sqrt(
            max(1.0 - cs * cs, 1e-6)
        ):
            n += 1.0
            cn += (norm - cn) / n
            cs += (sin_dip - cs) / n
            ae, an, au, be, bn, bu, s2 = band
            k1, k2 = c.k_band1, c.k_band2
            ae += k1 * (me / norm - ae)
            an += k1 * (mn / norm - an)
            au += k1 * (mu / norm - au)
            be += k2 * (ae - be)
            bn += k2 * (an - bn)
            bu += k2 * (au - bu)
            de, dn_, du = ae - be, an - bn, au - bu
            s2 += c.k_score * (de * de + dn_ * dn_ + du * du - s2)
            band = (ae, an, au, be, bn, bu, s2)
            # Timed only while the field stays put in the world (a candidate that moves is no new normal).
            bc = self._bcoef
            if s2 < 0.25 * _REJECT2 * (bc.wander_var + bc.drift_var * self._kf.u):
                timer += dt
                turn += sqrt(wx * wx + wy * wy + wz * wz) * dt
            self._mag_candidate = (cn, cs, n, turn, band)
            if timer > p.mag_reaccept_s and turn >= NEW_FIELD_TURN_RAD:
                # A different field that stayed steady this long is the new normal (moved robot, new mounting). Its
                # mean over the agreeing samples is the reference at once: no learning window, which would average
                # the outliers back in with the gate open.
                self._set_mag_reference(cn, cs, learn=False)
                # Its verdict carries over: it stayed put while timed.
                self._mag_band = band
                self._mag_curve = (band[3], band[4], band[5], 0.0)
                self._mag_band_t = t
                self._mag_consistent = True
                self._mag_weight = 1.0
                self._mag_steady_s = MAG_BAND_S[1]
                # The heading kept so far came from the old field (or the gyro since): it is re-acquired from the new
                # one, as at a start.
                self._var_head = max(self._var_head, (0.5 * math.pi) ** 2)
                return True
        else:
            timer -= _LEAK * dt
        if timer <= 0.0:
            # Not steady: start timing a new candidate field from this sample.
            u = (me / norm, mn / norm, mu / norm)
            self._mag_candidate = (norm, sin_dip, 1.0, 0.0, (*u, *u, 0.0))
            timer = 0.0
        self._mag_new_s = timer
        return False
