"""The NCF's integral: a Kalman filter on the gyroscope bias (rad/s, body), updated once per block of samples
spanning :data:`~ccf_ros.core.ccf.params.BIAS_UPDATE_PERIOD_S` from the NCF's tilt and heading errors (the
observation model and its noise: doc/algorithm.md)."""

from __future__ import annotations

from .discretisation import _BlockCoefficients
from .params import BIAS_GATE_SIGMAS

#: The gate (params.BIAS_GATE_SIGMAS), squared: the references' own errors are incl_sigma_rad and heading_sigma_rad
#: over tau_ncf_s.
_GATE2 = BIAS_GATE_SIGMAS**2
#: cos²(dip) is floored at this when the heading observations' noise is scaled by 1/cos²(dip) (near a magnetic pole
#: the horizontal field, and so heading, is lost in the tilt error).
_COS2_DIP_MIN = 0.05

Vec3 = tuple[float, float, float]
#: World east, north and up in body coordinates (the rows of the body->world rotation matrix), 3 x 3 flattened.
Axes = tuple[float, float, float, float, float, float, float, float, float]
#: A block's NCF heading errors: their sum (rad), how many (a count), the reference field's sin(dip) and the heading blend's
#: relative weight (1: a homogeneous field).
Heading = tuple[float, float, float, float]


class BiasKalman:
    """The bias's covariance ``p`` ((rad/s)², upper triangle ``p00, p01, p02, p11, p12, p22``), its mean relative to
    ``bias_sigma_init_rad_s²`` (``u``: 1 = nothing learnt) and the observation model's low-pass states (``model``;
    None: seeded at the next update). The bias itself is in the filter's per-sample state."""

    __slots__ = ('model', 'p', 'u')

    def __init__(self, var_init: float) -> None:
        self.set_prior(var_init, 1.0)
        self.model: tuple[tuple[float, ...], ...] | None = None

    def set_prior(self, var: float, u: float) -> None:
        """Covariance ``diag(var)`` ((rad/s)²) and its relative mean ``u`` (the observation model is kept)."""
        self.p = (var, 0.0, 0.0, var, 0.0, var)
        self.u = u

    def variance_along(self, x: float, y: float, z: float) -> float:
        """The bias's variance along the unit vector ``(x, y, z)`` (body), (rad/s)²: ``vᵀ P v``."""
        p00, p01, p02, p11, p12, p22 = self.p
        return x * (p00 * x + 2.0 * (p01 * y + p02 * z)) + y * (p11 * y + 2.0 * p12 * z) + p22 * z * z

    def update(
        self,
        c: _BlockCoefficients,
        n: float,
        bx: float, by: float, bz: float,
        axes: Axes,
        nx: float, ny: float, nz: float,
        heading: Heading | None,
        w2: float,
        learn: bool,
        at_rest: bool,
    ) -> Vec3:
        """The bias ``bx, by, bz`` (rad/s, body) after a block of ``n`` samples (``c``: the block span's constants).

        The arguments are the filter's step locals, the bias and the tilt error flat: a tuple per group costs ~0.1 µs
        to build and unpack, per block (per sample at 25 Hz and below). Observations: the NCF's tilt error (rad,
        body; ``nx, ny, nz``) seen in the world frame (east, north) and, with a
        usable magnetometer, its heading error (``heading``: the mean of the block's samples that qualified; a
        magnetometer sample's heading is noisy, the tilt error is low-passed), times ``1/tau_ncf_s``: the rate
        (rad/s) at which the gyro's attitude drifts from gravity and north. A bias error ``db`` (body) shows there as
        ``M(R db)``, ``M`` the low-passes it passed (Butterworth then NCF for tilt, NCF alone for heading), ``R`` the
        body->world rows ``axes``. The model runs the same low-passes on ``R`` and on ``R b`` (the estimate's own
        history), so the innovation is ``y + M(R b) - M(R) b``, and ``M(R)`` is the measurement matrix of a Kalman
        update, one scalar row at a time. ``w2``: the squared gyro rate, rad²/s². ``learn``: use the observations
        (not during the start-up, except in 6-D once the tilt is found; not at rest or without an accelerometer);
        ``at_rest``: the covariance relaxes to the rest's.
        """
        r0x, r0y, r0z, r1x, r1y, r1z, vx, vy, vz = axes
        rb0 = r0x * bx + r0y * by + r0z * bz
        rb1 = r1x * bx + r1y * by + r1z * bz
        rbv = vx * bx + vy * by + vz * bz
        model = self.model
        if model is None:
            # Seed at a standstill of the low-passes: the Butterworth values (and zero rates) of the tilt
            # quantities, the NCF outputs of the tilt quantities, and those of the heading ones.
            tilt = (r0x, r0y, r0z, r1x, r1y, r1z, rb0, rb1)
            model = self.model = (tilt, (0.0,) * 8, tilt, (vx, vy, vz, rbv))
        else:
            # Unrolled (this runs at 25 Hz, and a loop costs half again as much): Butterworth, then NCF low-pass,
            # of the tilt quantities u; NCF low-pass of the heading ones.
            (v0, v1, v2, v3, v4, v5, v6, v7), (d0, d1, d2, d3, d4, d5, d6, d7), mt, mh = model
            a, m12, m21, m22, k = c.m_a, c.m12, c.m21, c.m22, c.k_ncf
            e0, e1, e2, e3 = v0 - r0x, v1 - r0y, v2 - r0z, v3 - r1x
            e4, e5, e6, e7 = v4 - r1y, v5 - r1z, v6 - rb0, v7 - rb1
            v0 += m12 * d0 - a * e0
            v1 += m12 * d1 - a * e1
            v2 += m12 * d2 - a * e2
            v3 += m12 * d3 - a * e3
            v4 += m12 * d4 - a * e4
            v5 += m12 * d5 - a * e5
            v6 += m12 * d6 - a * e6
            v7 += m12 * d7 - a * e7
            o0, o1, o2, o3, o4, o5, o6, o7 = mt
            h0, h1, h2, h3 = mh
            model = self.model = (
                (v0, v1, v2, v3, v4, v5, v6, v7),
                (m21 * e0 + m22 * d0, m21 * e1 + m22 * d1, m21 * e2 + m22 * d2, m21 * e3 + m22 * d3,
                 m21 * e4 + m22 * d4, m21 * e5 + m22 * d5, m21 * e6 + m22 * d6, m21 * e7 + m22 * d7),
                (o0 + k * (v0 - o0), o1 + k * (v1 - o1), o2 + k * (v2 - o2), o3 + k * (v3 - o3),
                 o4 + k * (v4 - o4), o5 + k * (v5 - o5), o6 + k * (v6 - o6), o7 + k * (v7 - o7)),
                (h0 + k * (vx - h0), h1 + k * (vy - h1), h2 + k * (vz - h2), h3 + k * (rbv - h3)),
            )
        p00, p01, p02, p11, p12, p22 = self.p
        if learn and c.motion_bias:
            # Observation noise: (walk tau_bias)² per block, growing with the rotation rate; heading's over cos²(dip).
            r = c.r_tilt * (1.0 + w2 * c.inv_rot2)
            k = -c.inv_tau_ncf
            y0 = k * (r0x * nx + r0y * ny + r0z * nz)
            y1 = k * (r1x * nx + r1y * ny + r1z * nz)
            mt, mh = model[2], model[3]
            # (the row's M(R), its M(R b), the observation, its variance, the gate's noise floor)
            rows = [(mt[0], mt[1], mt[2], mt[6], y0, r, c.gate_tilt), (mt[3], mt[4], mt[5], mt[7], y1, r, c.gate_tilt)]
            if heading is not None:
                # The block's mean heading error; its variance grows as fewer of the block's samples qualified.
                h_sum, h_n, sd, wgt = heading
                rows.append((*mh, k * h_sum / h_n, r * n / (h_n * wgt * wgt * max(1.0 - sd * sd, _COS2_DIP_MIN)),
                             c.gate_head))
            for h0, h1, h2, hb, y, ri, floor2 in rows:
                nu = y + hb - (h0 * bx + h1 * by + h2 * bz)
                ph0 = p00 * h0 + p01 * h1 + p02 * h2
                ph1 = p01 * h0 + p11 * h1 + p12 * h2
                ph2 = p02 * h0 + p12 * h1 + p22 * h2
                hph = h0 * ph0 + h1 * ph1 + h2 * ph2
                if nu * nu > _GATE2 * (hph + floor2) and hph < c.gate_p:
                    # More drift than the bias's uncertainty and the accelerometer's (magnetometer's) own error
                    # explain: a linear acceleration that lasts (a vehicle drives off, brakes, turns), a shock. It is
                    # no information about the bias, once the bias is roughly known (before, a bias beyond the
                    # initial uncertainty, a cheap gyro's 2°/s, must still be learnt).
                    continue
                si = 1.0 / (hph + ri)
                k0, k1, k2 = ph0 * si, ph1 * si, ph2 * si
                bx += k0 * nu
                by += k1 * nu
                bz += k2 * nu
                p00 -= k0 * ph0
                p01 -= k0 * ph1
                p02 -= k0 * ph2
                p11 -= k1 * ph1
                p12 -= k1 * ph2
                p22 -= k2 * ph2
        if at_rest:
            # At rest the covariance relaxes to bias_sigma_rest² (the low-passed gyro's own uncertainty).
            kr = c.keep_rest
            pr = (1.0 - kr) * c.p_rest
            p00, p11, p22 = p00 * kr + pr, p11 * kr + pr, p22 * kr + pr
            p01 *= kr
            p02 *= kr
            p12 *= kr
        else:
            # The bias random walk: knowledge ages (up to knowing nothing).
            pi, w = c.p_init, c.walk
            if p00 < pi:
                p00 += w
            if p11 < pi:
                p11 += w
            if p22 < pi:
                p22 += w
        # A variance cannot be negative; rounding after an update from far more information than the prior (an
        # extreme bias_sigma_init_rad_s) could leave it so.
        p00 = p00 if p00 > 0.0 else 0.0
        p11 = p11 if p11 > 0.0 else 0.0
        p22 = p22 if p22 > 0.0 else 0.0
        self.p = (p00, p01, p02, p11, p12, p22)
        self.u = (p00 + p11 + p22) / (3.0 * c.p_init)
        return bx, by, bz

