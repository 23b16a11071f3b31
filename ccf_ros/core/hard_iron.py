"""Online hard-iron estimation: the magnetometer offset that turns with the body, told from a field fixed in the world.

Model: ``m_k = R_k^T f + b`` with ``b`` the offset (body frame), ``f`` the field in the world and ``R_k`` the
orientation (body -> world). Between two samples ``j`` and ``k`` the body's turn is ``M = R_k^T R_j``, and
``m_k - b = M (m_j - b)`` whatever ``f`` is: ``(I - M) b = m_k - M m_j``, linear in ``b``, free of the heading and of
the world field. ``R`` is the filter's own orientation (:meth:`HardIronEstimator.pair`, no second gyro integration):
over a pair it differs from the gyro's by the filter's corrections, small (doc/magnetometer_calibration.md), and each
pair's component that a heading correction reaches is left out (``_fold``). A body-fixed offset satisfies it at
every pair; a field that changes in the world as the sensor moves (a magnet in the room, steel in the floor) does not,
and shows as a residual. The pairs span up to :data:`MAX_LAG_S` and at least :data:`MIN_PAIR_ANGLE_RAD` of turn (a
smaller turn says little of ``b``).

Least squares with forgetting by rotation: every pair's information decays by ``exp(-turn / memory_rad)``, so the
estimate remembers the latest ``memory_rad`` of rotation and nothing is forgotten (or learnt) at rest. A second, short
memory (:data:`SHORT_MEMORY_SHARE`) tells an offset that changed (a magnet attached or taken off: only the recent pairs
fit) from a field that changes in the world (neither fits). The offset is applied once at least :data:`MIN_PAIRS`
pairs are in, its largest standard deviation is below :data:`SIGMA_APPLY_REL` of the field norm, the model's residual
is below :data:`RESIDUAL_MAX_REL` of it, with it subtracted the field's norm and vertical component spread less than
:data:`LEVEL_SPREAD_MAX_REL`, it explains :data:`EXPLAINED_MIN` of the pairs' variation and, for a first offset, it
is larger than :data:`APPLY_MIN_REL` of the norm and explains :data:`EXPLAINED_FIRST` (or :data:`FIRST_MIN_PAIRS`
pairs stand behind it); while
the model does not fit, nothing new is applied (what was applied stays). Thresholds are relative to the field norm,
so the field's unit does not matter.

Numpy and the standard library only.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any, NamedTuple

import numpy as np

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]

#: Pairs are at most this far apart, s (gyro drift: 0.3 deg/s of bias over 1 s is 0.3 % of the field).
MAX_LAG_S = 1.0
#: ... and turned at least this much relative to each other, rad.
MIN_PAIR_ANGLE_RAD = 0.15
_COS_HALF_MIN_PAIR = math.cos(0.5 * MIN_PAIR_ANGLE_RAD)
#: One pair per this period, s (cost; neighbouring samples add little).
UPDATE_PERIOD_S = 0.1
#: The pairs are added to the memories (vectorised) and the estimate solved for (the decision taken) every this many
#: pairs (5 s of turning: the per-call cost of numpy, not the pairs', is what costs).
SOLVE_EVERY = 50
#: ... every this many pairs after a decision that moved the applied offset (0.5 s of turning: it is being refined).
SOLVE_EVERY_MOVING = 5
#: A gap between kept samples longer than this (s) forgets the stored ones (no pair spans it).
MAX_DT_S = 0.5
#: Applied once the largest standard deviation of the estimate is below this fraction of the field norm.
SIGMA_APPLY_REL = 0.02
#: ... and the model's RMS residual per axis below this fraction of the field norm (else: a world-fixed disturbance).
RESIDUAL_MAX_REL = 0.04
#: Residual floor in the covariance, fraction of the field norm: not more confident than the sensor's noise.
RESIDUAL_FLOOR_REL = 0.01
#: The applied offset follows the estimate when they differ by more than this fraction of the field norm (and 2 sigma).
APPLY_FOLLOW_REL = 0.002
#: A change of the applied offset larger than this fraction of the field norm is a jump: the filter is told.
APPLY_STEP_REL = 0.01
#: Fewest (forgotten-weighted) pairs before anything is applied (3 s of turning).
MIN_PAIRS = 30
#: The short memory (which tells a changed offset) is this share of ``memory_rad``.
SHORT_MEMORY_SHARE = 0.2
#: A first offset is applied only if larger than this fraction of the field norm (see ``_decide``).
APPLY_MIN_REL = 0.06
#: Leave out each pair's component that the filter's heading corrections reach (see ``_update``).
PROJECT_HEADING = True
#: Apply only if, with the offset subtracted, the field's norm and vertical component stay within this RMS spread
#: (fraction of the field norm) over the memory (see ``_Fit.consistent``).
LEVEL_SPREAD_MAX_REL = 0.05
#: ... and only if the estimate explains at least this share of the pairs' sum of squares (see ``_Fit.consistent``).
EXPLAINED_MIN = 0.1
#: A first offset needs to explain this share of the pairs' sum of squares, or to have this many (forgotten-weighted)
#: pairs behind it (see ``_decide``).
EXPLAINED_FIRST = 0.5
FIRST_MIN_PAIRS = 150
#: Equations per pair.
_DOF = 2.0 if PROJECT_HEADING else 3.0
#: Statuses of :class:`HardIronStatus`.
STATUSES = ('not_determined', 'tracking', 'applied')


class HardIronStatus(NamedTuple):
    """status: ``'not_determined'`` (too little rotation: the estimate's sigma is above the threshold),
    ``'tracking'`` (determined, but the body-fixed model does not hold: a world-fixed disturbance; nothing new is
    applied) or ``'applied'`` (the applied offset follows the estimate). offset: applied offset (field unit);
    estimate: latest estimate; sigma: its standard deviations; residual_rel: RMS model residual per axis over the
    field norm; rotation_rad: rotation the estimate has seen (total, not forgotten)."""

    status: str
    offset: Vec3
    estimate: Vec3
    sigma: Vec3
    residual_rel: float
    rotation_rad: float


def _mul(a: Quat, b: Quat) -> Quat:
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw)


def _dot(a: Quat, b: Quat) -> float:
    """Dot product of two quaternions: the cosine of half the rotation between two unit ones."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]


def _matrices(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (k, 3, 3) of unit quaternions ``q`` (k, 4) [w, x, y, z]: ``(w² - |v|²) I + 2 v v^T + 2 w [v]x``
    (few numpy calls: their count, not the arithmetic, is the cost)."""
    w, v = q[:, 0], q[:, 1:]
    R: np.ndarray = 2.0 * v[:, :, None] * v[:, None, :]
    R[:, _DIAG, _DIAG] += (w * w - (v * v).sum(axis=1))[:, None]
    wv = 2.0 * w[:, None] * v
    R[:, _SKEW_I, _SKEW_J] += wv[:, _SKEW_K] * _SKEW_SIGN
    return R


_DIAG = np.arange(3)
# [v]x: (i, j) = -v_k for (0,1,2), (1,2,0), (2,0,1); +v_k for the transposed.
_SKEW_I = np.array([0, 1, 2, 1, 2, 0])
_SKEW_J = np.array([1, 2, 0, 0, 1, 2])
_SKEW_K = np.array([2, 0, 1, 2, 0, 1])
_SKEW_SIGN = np.array([-1.0, -1.0, -1.0, 1.0, 1.0, 1.0])
_CROSS_1 = np.array([1, 2, 0])
_CROSS_2 = np.array([2, 0, 1])


class _Fit:
    """The forgotten least-squares sums of one memory and their solution."""

    def __init__(self) -> None:
        self.H = np.zeros((3, 3))
        self.g = np.zeros(3)
        self.yy = 0.0
        self.n = 0.0
        self.s1 = np.zeros(3)  # sums of m and |m|^2 and their weight: the field norm for any b
        self.s2 = 0.0
        self.w = 0.0
        # Sums of phi = (|m|², m, up·m, up) and phi phi^T: the spread of the field's norm and vertical component for
        # any b (see level_spread).
        self.p1 = np.zeros(8)
        self.p2 = np.zeros((8, 8))
        self.pw = 0.0  # their weight (0 after restoring a state without them)
        self.level_spread = math.inf
        self.explained = 0.0  # share of the pairs' sum of squares the estimate explains
        self.estimate = np.zeros(3)
        self.sigma = np.full(3, math.inf)
        self.residual_rel = math.inf
        self.norm = 0.0
        self.determined = False

    def copy(self) -> _Fit:
        out = _Fit()
        out.__dict__.update({k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in self.__dict__.items()})
        return out

    def add(self, lam: np.ndarray, A: np.ndarray, y: np.ndarray, m: np.ndarray, phi: np.ndarray) -> None:
        """Add pairs in order, each decaying the sums before it by its ``lam`` (k,): ``A b = y`` (k, 3, 3), (k, 3),
        the samples ``m`` (k, 3) and their level features ``phi`` (k, 8)."""
        # Weight of pair i at the end: the decays of the pairs after it.
        c = np.concatenate((np.cumprod(lam[::-1])[::-1][1:], [1.0]))
        d = float(np.prod(lam))
        cs = float(c.sum())
        Ac = A * c[:, None, None]
        self.p1 = d * self.p1 + c @ phi
        self.p2 = d * self.p2 + (phi.T * c) @ phi
        self.pw = d * self.pw + cs
        self.H = d * self.H + np.tensordot(Ac, A, axes=((0, 1), (0, 1)))
        self.g = d * self.g + np.tensordot(Ac, y, axes=((0, 1), (0, 1)))
        self.yy = d * self.yy + float(c @ (y * y).sum(axis=1))
        self.n = d * self.n + cs
        self.s1 = d * self.s1 + c @ m
        self.s2 = d * self.s2 + float(c @ phi[:, 0])
        self.w = d * self.w + cs

    def solve(self) -> None:
        """Estimate, its sigma, the model residual and whether it is determined (sigma small, enough pairs)."""
        try:
            H_inv = np.linalg.inv(self.H)
        except np.linalg.LinAlgError:
            return
        b = H_inv @ self.g
        # Field norm at this offset: mean |m - b|^2 from the sums.
        norm2 = (self.s2 - 2.0 * float(b @ self.s1)) / self.w + float(b @ b) if self.w > 0 else 0.0
        if not (np.all(np.isfinite(b)) and norm2 > 0):
            return
        norm = math.sqrt(norm2)
        resid = math.sqrt(max(self.yy - float(b @ self.g), 0.0) / max(_DOF * self.n - 3.0, 1.0))
        s2 = max(resid, RESIDUAL_FLOOR_REL * norm) ** 2
        self.estimate, self.norm = b, norm
        self.sigma = np.sqrt(np.maximum(np.diag(H_inv), 0.0) * s2)
        self.residual_rel = resid / norm
        self.level_spread = self._level_spread(b, norm)
        self.explained = float(b @ self.g) / self.yy if self.yy > 0.0 else 0.0
        self.determined = (self.n >= MIN_PAIRS
                           and float(np.max(np.linalg.eigvalsh(H_inv))) * s2 < (SIGMA_APPLY_REL * norm) ** 2)

    def _level_spread(self, b: np.ndarray, norm: float) -> float:
        """The larger RMS spread, over the memory, of the field's norm and of its vertical component (both free of
        the heading) with ``b`` subtracted, as a fraction of the field norm ``norm``."""
        if self.pw <= 0.0:
            return math.inf
        spreads = []
        # |m - b|² = |m|² - 2 b·m + |b|²: its spread over (2 norm²) is the norm's relative spread; up·(m - b) over norm.
        for c, scale in ((np.concatenate(([1.0], -2.0 * b, [0.0], np.zeros(3))), 2.0 * norm * norm),
                         (np.concatenate(([0.0], np.zeros(3), [1.0], -b)), norm)):
            mean = float(c @ self.p1) / self.pw
            var = float(c @ self.p2 @ c) / self.pw - mean * mean
            spreads.append(math.sqrt(max(var, 0.0)) / scale)
        return max(spreads)

    @property
    def consistent(self) -> bool:
        """Determined, the body-fixed model explains the pairs, and with the offset subtracted the field's norm and
        vertical component stay put (a field fixed in the world that varies with position does not)."""
        if not (self.determined and self.residual_rel <= RESIDUAL_MAX_REL
                and self.level_spread <= LEVEL_SPREAD_MAX_REL):
            return False
        # A real offset explains the pairs' differences it causes; a spurious one (a field that varies with position,
        # correlated with the turns for a while) explains little of them. (An estimate near 0 claims nothing.)
        return self.explained >= EXPLAINED_MIN or float(self.estimate @ self.estimate) < (APPLY_MIN_REL * self.norm) ** 2


class HardIronEstimator:
    """Recursive least-squares estimate of a body-fixed magnetometer offset from magnetometer samples and the filter's
    orientation at them.

    Two memories: ``memory_rad`` (the estimate) and :data:`SHORT_MEMORY_SHARE` of it. When the long one no longer
    fits (an offset that changed: a magnet attached or taken off) but the short one does, the long one restarts from
    the short one; when neither fits (a field that changes in the world), nothing new is applied.
    """

    def __init__(self, memory_rad: float = 60.0) -> None:
        if not (isinstance(memory_rad, (int, float)) and math.isfinite(memory_rad) and memory_rad > 0):
            raise ValueError(f'mag_online_memory_rad must be a finite number > 0, got {memory_rad!r}')
        self.memory_rad = float(memory_rad)
        self._long = _Fit()
        self._short = _Fit()
        self._offset: Vec3 = (0.0, 0.0, 0.0)
        #: the applied offset (field unit, body frame), None while it is zero (nothing to subtract)
        self.offset: Vec3 | None = None
        self._status = 'not_determined'
        #: the magnetometer sample (stamp s, field) waiting for :meth:`pair` (None: none due)
        self.pending: tuple[float, Vec3] | None = None
        #: a magnetometer sample at or after this stamp is kept for pairing (s; see :meth:`due`)
        self.t_next = -math.inf
        self._restart(-math.inf)
        self.rotation_rad = 0.0
        self._pairs = 0
        self._solve_every = SOLVE_EVERY
        #: pairs not yet added to the memories: (r (4), q (4), m (3), m_j (3), turn) each
        self._batch: list[tuple[float, ...]] = []
        #: the applied offset changed at the latest :meth:`correct` (the caller tells its filter)
        self.jumped = False
        #: how far off the field measured before the latest jump may have been, over the field norm (the caller
        #: tells its filter): the larger of the jump and the new offset
        self.change_rel = 0.0

    def _restart(self, t_s: float) -> None:
        """Forget the stored samples (a gap, a clock jump, a filter restart); the estimate is kept."""
        self.t_next = t_s
        self._history: deque[tuple[float, Quat, Vec3]] = deque()
        self._turn = 0.0  # rotation since the last accumulated pair, rad
        self._q_last: Quat | None = None
        self._epoch: object = None
        self._count = 0

    def correct(self, t_s: float, mag: Vec3 | None) -> Vec3 | None:
        """One IMU sample's stamp (s) and paired magnetometer sample (or None): the sample minus the applied offset
        (None if none). The sample is kept as :attr:`pending` when due (:meth:`due`), to be paired by :meth:`pair`
        with the orientation the filter reaches at it. (The engine's per-sample path, message by message and in bulk;
        ``ImuEngine.on_imu`` and ``on_chunk`` write out this and :meth:`due` for a sample not due: they change together.)"""
        if mag is None:
            return None
        if self.due(t_s):
            self.pending = (t_s, mag)
        o = self.offset
        return mag if o is None else (mag[0] - o[0], mag[1] - o[1], mag[2] - o[2])

    def due(self, t_s: float) -> bool:
        """Whether a magnetometer sample at ``t_s`` (s) is to be kept (every :data:`UPDATE_PERIOD_S`; at once when the
        clock went back); if so the next is due a period later."""
        d = t_s - self.t_next
        if d >= 0.0 or d < -UPDATE_PERIOD_S:
            self.t_next = t_s + UPDATE_PERIOD_S
            return True
        return False

    def pair(self, q: Quat | None, epoch: object = None, count: int = 0) -> None:
        """Pair :attr:`pending` with ``q``, the filter's body->world orientation [w, x, y, z] at its stamp (None: the
        filter has none). ``epoch`` names the filter's continuity, ``count`` the samples it has processed: stored
        samples of another epoch, or from before a smaller count (a reset), are forgotten (the orientation jumps
        there). Sets :attr:`jumped`."""
        self.jumped = False
        p, self.pending = self.pending, None
        if p is None:
            return
        t_s, mag = p
        hist = self._history
        if (q is None or epoch != self._epoch or count < self._count
                or (hist and not 0.0 < t_s - hist[-1][0] <= MAX_DT_S)):
            self._restart(t_s)
            self.t_next = t_s + UPDATE_PERIOD_S
            self._epoch = epoch
            if q is None:
                return
        self._count = count
        if not all(math.isfinite(v) for v in mag):
            return
        q_last = self._q_last
        if q_last is not None:
            # The rotation between stored samples, for the forgetting (the gyro's turn, through the filter).
            step = 2.0 * math.acos(min(1.0, abs(_dot(q_last, q))))
            self._turn += step
            self.rotation_rad += step
        self._q_last = q
        self._update(t_s, q, (float(mag[0]), float(mag[1]), float(mag[2])))

    def _update(self, t_s: float, q: Quat, m: Vec3) -> None:
        """Pair ``m`` (orientation ``q``) with the oldest stored sample within :data:`MAX_LAG_S`, accumulate,
        re-solve, decide."""
        hist = self._history
        while hist and t_s - hist[0][0] > MAX_LAG_S:
            hist.popleft()
        hist.append((t_s, q, m))
        if len(hist) < 2:
            return
        _, q_j, m_j = hist[0]
        if abs(_dot(q, q_j)) > _COS_HALF_MIN_PAIR:  # turned less than MIN_PAIR_ANGLE_RAD
            return
        r = _mul((q[0], -q[1], -q[2], -q[3]), q_j)  # body j -> body k
        turn, self._turn = self._turn, 0.0
        self._batch.append((*r, *q, *m, *m_j, turn))
        self._pairs += 1
        if len(self._batch) >= self._solve_every:
            self._fold()
            before = self._offset
            self._decide()
            # While the applied offset moves (being refined), the next decision comes sooner.
            self._solve_every = SOLVE_EVERY_MOVING if self._offset != before else SOLVE_EVERY

    def _fold(self) -> None:
        """Add the batch of pairs to both memories (vectorised: numpy's per-call cost, not the pairs', dominates)."""
        x = np.array(self._batch)
        self._batch = []
        k = len(x)
        R = _matrices(x[:, 0:8].reshape(2 * k, 4))  # (one call for both: numpy's per-call cost is what counts)
        M = R[0::2]
        up = R[1::2, 2, :]  # the world's up in the body frame
        m, m_j, turn = x[:, 8:11], x[:, 11:14], x[:, 14]
        A = np.eye(3) - M
        y = m - (M @ m_j[:, :, None])[:, :, 0]
        if PROJECT_HEADING:
            # The filter's heading corrections over the pair turn M about the world's vertical by a small unknown
            # angle: an error along u = up x (m - b) (the horizontal field turned by 90°, body frame). That component
            # of the pair is left out (2 of its 3 equations kept), so no heading correction, however large, enters.
            h = m - self._long.estimate
            u = up[:, _CROSS_1] * h[:, _CROSS_2] - up[:, _CROSS_2] * h[:, _CROSS_1]  # up x h (np.cross costs 10x)
            nu = (u * u).sum(axis=1)
            u = u / np.sqrt(np.where(nu > 0.0, nu, 1.0))[:, None]
            A = A - u[:, :, None] * (u[:, None, :] @ A)
            y = y - u * (u * y).sum(axis=1)[:, None]
        phi = np.concatenate(((m * m).sum(axis=1)[:, None], m, (up * m).sum(axis=1)[:, None], up), axis=1)
        self._long.add(np.exp(-turn / self.memory_rad), A, y, m, phi)
        self._short.add(np.exp(-turn / (SHORT_MEMORY_SHARE * self.memory_rad)), A, y, m, phi)

    def _decide(self) -> None:
        """Solve both memories; restart the long one from the short one if only the short one fits; apply."""
        long, short = self._long, self._short
        long.solve()
        short.solve()
        if short.consistent and long.determined and not long.consistent:
            # The offset changed (a magnet attached or taken off): the old pairs no longer fit, the recent ones do.
            self._long = long = short.copy()
        if not long.consistent:
            # What was applied stays (frozen) rather than follow a disturbance or go back to nothing.
            self._status = 'tracking' if long.determined or self._status != 'not_determined' else 'not_determined'
            return
        b = long.estimate
        o = np.array(self._offset)
        step = float(np.linalg.norm(b - o))
        # A first offset (or one back to 0) must be significant: smaller ones are the room's non-uniformity as
        # much as the sensor's (BROAD's calibrated trials show 1-2.5 uT when translated), left to calibrate-mag.
        applied = self._status == 'applied' or any(self._offset)
        if not applied and (float(np.linalg.norm(b)) < APPLY_MIN_REL * long.norm
                            or (long.explained < EXPLAINED_FIRST and long.n < FIRST_MIN_PAIRS)):
            self._status = 'tracking'
            return
        self._status = 'applied'
        if step > max(APPLY_FOLLOW_REL * long.norm, 2.0 * float(np.max(long.sigma))):
            self._set_offset((float(b[0]), float(b[1]), float(b[2])))
            # Refinements are within the filter's disturbance tolerances; a jump is not.
            self.jumped = step > APPLY_STEP_REL * long.norm
            # The jump is the error of the samples corrected before it, if the new offset is right. A large offset
            # is never quite right: a magnet close to the sensor leaves more than an offset unmodelled (BROAD 33's,
            # 60 % of the norm, leaves the corrected field wandering by 4.3° RMS at the next decision).
            self.change_rel = max(step, float(np.linalg.norm(b))) / long.norm

    def _set_offset(self, o: Vec3) -> None:
        self._offset = o
        self.offset = o if any(o) else None

    def status(self) -> HardIronStatus:
        """The estimator's :class:`HardIronStatus`."""
        f = self._long
        e, s = f.estimate, f.sigma
        return HardIronStatus(self._status, self._offset, (float(e[0]), float(e[1]), float(e[2])),
                              (float(s[0]), float(s[1]), float(s[2])), float(f.residual_rel), self.rotation_rad)

    def state(self) -> dict[str, Any]:
        """Everything needed to continue after a restart, as plain floats and lists (for a YAML/JSON file)."""
        # The pairs since the latest decision folded in and solved for (what restore() continues from), on copies:
        # saving must not change what comes next (a node saves its bias_file every few seconds of wall time and must
        # still answer as replay does).
        live = (self._long, self._short, self._batch)
        self._long, self._short = self._long.copy(), self._short.copy()
        try:
            if self._batch:
                self._fold()
            f = self._long
            f.solve()
        finally:
            self._long, self._short, self._batch = live
        return {
            'status': self._status, 'offset': list(self._offset), 'estimate': [float(v) for v in f.estimate],
            'sigma': [float(v) for v in f.sigma], 'information': [float(v) for v in f.H.ravel()],
            'vector': [float(v) for v in f.g], 'yy': f.yy, 'n': f.n,
            'sum_m': [float(v) for v in f.s1], 'sum_m2': f.s2, 'weight': f.w,
            'level_sum': [float(v) for v in f.p1], 'level_sum2': [float(v) for v in f.p2.ravel()],
            'level_weight': f.pw, 'rotation_rad': self.rotation_rad,
        }

    def restore(self, state: dict[str, Any]) -> None:
        """Continue from :meth:`state`'s output (the short memory starts empty). Raises ValueError (naming the
        field) on a malformed state; the estimator is unchanged then."""
        try:
            H = np.array(state['information'], dtype=float).reshape(3, 3)
            g = np.array(state['vector'], dtype=float).reshape(3)
            s1 = np.array(state['sum_m'], dtype=float).reshape(3)
            offset = np.array(state['offset'], dtype=float).reshape(3)
            scalars = [float(state[k]) for k in ('yy', 'n', 'sum_m2', 'weight', 'rotation_rad')]
            # (Absent from states written before the level test: the spread is learnt anew.)
            p1 = np.array(state.get('level_sum', np.zeros(8)), dtype=float).reshape(8)
            p2 = np.array(state.get('level_sum2', np.zeros(64)), dtype=float).reshape(8, 8)
            pw = float(state.get('level_weight', 0.0))
            status = str(state['status'])
        except (KeyError, TypeError, ValueError) as err:
            raise ValueError(f'hard_iron state is malformed: {err!r}') from None
        values = np.concatenate((H.ravel(), g, s1, offset, scalars, p1, p2.ravel(), [pw]))
        if not np.all(np.isfinite(values)) or status not in STATUSES:
            raise ValueError(f'hard_iron state has a non-finite value or an unknown status {status!r}')
        f = _Fit()
        f.H, f.g, f.s1 = H, g, s1
        f.yy, f.n, f.s2, f.w, self.rotation_rad = scalars
        f.p1, f.p2, f.pw = p1, p2, pw
        if f.w > 0:
            f.solve()
        self._long, self._short = f, _Fit()
        self._batch = []
        self._set_offset((float(offset[0]), float(offset[1]), float(offset[2])))
        self._status = status
