"""The adaptive basis algorithm of paper 003: line sensors and straight passes from detection times.

Model (paper 003 §3). Sensor k's beam is the line a_k·x + b_k·y = 1 (eq. 1); object l moves
as p_l(t) = (x0_l + vx_l·t, y0_l + vy_l·t) (eq. 2); sensor k detects it at the time t_kl with
a_k·p_l(t_kl) = 1 (eq. 3). The estimates minimise the sum of squared equation errors
τ_kl = a_k·(vx_l·t_kl + x0_l) + b_k·(vy_l·t_kl + y0_l) − 1 (eqs. 4–5) over the measurements that
are known (the view Ω of eq. 21). Nothing but detection times is needed.

* **Phase 1** (§5.1, :func:`closed_form`): the *adaptive coordinate system* — object o1 moves
  along the x axis at speed 1 and is at the origin at a reference time, o2 moves along the y axis
  at speed 1 from an unknown point (x̃0_o2, ỹ0_o2) — in which the beams of ≥ 6 sensors and the
  passes o1…o3 follow in closed form (eqs. 9–20); of the two roots of the quadratic (eq. 20) the
  one whose beams fit o4's detection times is kept.
* **Phase 2** (§5.2, :class:`AdaptiveBasis`): as objects (and sensors) arrive, block-coordinate
  Newton steps on eq. 23 — per sensor on (a, b) (eqs. 24–26), per object on
  (vx, x0, vy, y0) — five iterations per pass by default. The cost is quadratic in each block, so
  each Newton step is that block's exact minimiser and the cost (eq. 5) never increases.
* **Phase 3** (§5.3, §7.1, :class:`Frame`): the affine map x_adaptive = A·x_real + d (eq. 27) to
  real-world coordinates, from known sensor positions (eqs. 28–30), known beams, or known
  trajectories (calibration passes, eqs. 32–33), by linear least squares.

Units: times in s; in the adaptive frame lengths are "o1-seconds" (o1 travels one unit per s);
real-world lengths are the deployment's units. Times are handled relative to a per-object
reference time (the mean of that object's detection times) so that large clock values (epoch
seconds) lose no precision; this is a linear reparametrisation of (vx, x0, vy, y0), under which
Newton steps are unchanged. The data's clock may even differ per object (the paper's simulation
times each object from its own entry).

Everything here is pure numpy: deterministic, no I/O.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from bintrack.errors import BintrackError

# Phase 1 needs six sensors and three objects (eq. 8: nm ≥ 4(n − 2) + 2 + 2m), a fourth object to
# choose the root, and on that fourth object more detections than its four unknowns.
PHASE1_SENSORS = 6
PHASE1_OBJECTS = 4
SIGN_DETECTIONS = 5
OBJECT_UNKNOWNS = 4
LINE_UNKNOWNS = 2
PHASE1_WINDOW = 12  # phase 1 looks for its four objects among this many consecutive ones
DEFAULT_ITERATIONS = 5  # §7.2: "The number of iterations of Newton's method was fixed to 5"
RANK_RTOL = 1e-7  # relative singular value below which a (column-normalised) system is singular
# phase 1's fourth-object check: RMS time residual at most this fraction of its detection span
CONSISTENCY_RTOL = 0.05
COND_MAX = 1e12  # a block whose (scaled) Newton matrix is worse conditioned is not updated
PHASE2_METHODS = ("lsq", "paper")
SOLVE_XTOL = 1e-10  # relative step at which the least-squares phase 2 stops
SOLVE_FTOL = 1e-15
SOLVE_GTOL = 1e-15
SOLVE_MAX_NFEV: int | None = None


class DegenerateError(BintrackError, ValueError):
    """Input the algorithm cannot solve (paper 003 §3: e.g. the first two objects parallel, all
    beams parallel, sensor positions collinear); the text says which, in one line."""


# --------------------------------------------------------------------------- small geometry


def line_through(p: Sequence[float], q: Sequence[float]) -> np.ndarray:
    """(a, b) of the line a·x + b·y = 1 through points ``p`` and ``q`` (eq. 9); DegenerateError
    if the line passes through the origin (it has no such form) or p = q."""
    m = np.array([p, q], dtype=float)
    det = m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]
    scale = max(float(np.abs(m).max()), 1e-300) ** 2
    if abs(det) <= 1e-12 * scale:
        raise DegenerateError("a beam passes through the origin of the adaptive frame")
    return np.linalg.solve(m, np.ones(2))


def _null_vector(m: np.ndarray, what: str) -> np.ndarray:
    """The (column-scaled) right singular vector of ``m`` for its smallest singular value;
    DegenerateError if the null space is more than one-dimensional."""
    scale = np.linalg.norm(m, axis=0)
    if np.any(scale == 0):
        raise DegenerateError(f"{what}: a column of the system is zero")
    _, s, vt = np.linalg.svd(m / scale)
    if m.shape[0] >= m.shape[1] - 1 and s[m.shape[1] - 2] <= RANK_RTOL * s[0]:
        raise DegenerateError(f"{what}: the solution is not unique")
    return vt[-1] / scale


def _lstsq_rank(m: np.ndarray, rhs: np.ndarray, what: str) -> np.ndarray:
    """Least-squares solution of m·u = rhs, columns scaled; DegenerateError if rank-deficient."""
    scale = np.linalg.norm(m, axis=0)
    scale[scale == 0] = 1.0
    u, s, vt = np.linalg.svd(m / scale, full_matrices=False)
    if len(s) < m.shape[1] or s[-1] <= RANK_RTOL * s[0]:
        raise DegenerateError(what)
    return (vt.T @ ((u.T @ rhs) / s)) / scale


def predicted_times(lines: np.ndarray, centre: np.ndarray, velocity: np.ndarray, t_ref: float) -> np.ndarray:
    """Detection times (s) of an object at ``centre`` at time ``t_ref`` moving at ``velocity`` by
    beams ``lines`` (k × 2): eq. 3 without noise; inf where a beam is parallel to the motion."""
    rate = lines @ velocity
    with np.errstate(divide="ignore", invalid="ignore"):
        return t_ref + (1.0 - lines @ centre) / rate


def fit_object(lines: np.ndarray, times: np.ndarray, t_ref: float) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares pass (centre at ``t_ref``, velocity) through beams ``lines`` (k × 2) crossed at
    ``times`` (s): minimises eq. 5 over one object (its exact Newton step). Needs k ≥ 4."""
    tau = np.asarray(times, dtype=float) - t_ref
    a, b = lines[:, 0], lines[:, 1]
    m = np.stack([a * tau, a, b * tau, b], axis=1)
    vx, cx, vy, cy = _lstsq_rank(m, np.ones(len(tau)), "object: its detections do not fix its path")
    return np.array([cx, cy]), np.array([vx, vy])


# --------------------------------------------------------------------------- phase 1


@dataclass(frozen=True)
class Phase1Solution:
    """Phase 1 in the adaptive frame (o1 at the origin at ``t_origin``, velocity (1, 0); o2
    velocity (0, 1)).

    ``lines`` (m × 2): the sensors' beams (a, b) in adaptive units⁻¹. ``centres`` and
    ``velocities`` (4 × 2): objects o1…o4 at their reference times ``t_refs`` (s, the mean of each
    one's detection times). ``roots``: both candidates (x̃0_o2, ỹ0_o2) of eq. 20 at o2's reference
    time; ``residuals`` (s): RMS time residual of o4 under each; ``chosen``: the index of the root
    kept."""

    lines: np.ndarray
    centres: np.ndarray
    velocities: np.ndarray
    t_refs: np.ndarray
    t_origin: float
    roots: tuple[tuple[float, float], ...]
    residuals: tuple[float, ...]
    chosen: int


def _phase1_candidates(theta: np.ndarray) -> list[tuple[float, float]]:
    """Real roots (x̃0_o2, ỹ0_o2) of eq. 19 given θ1…θ6 (eq. 18 normalised to α5 = 1).

    With v = [x2·y3 − y2·x3, y2 − y3, −x3, x2·vy3 − y2·vx3, −vy3, −vx3, 1] (the coefficients of
    e, T1, T2, T3, T1∘T3, T2∘T3, T1∘T2 in eq. 12), θ4 = −θ5·x2 + θ6·y2 is a line in (x2, y2) and
    θ1 = x2·y2 − θ2·x2 + θ3·y2 a hyperbola; their intersections are the quadratic of eq. 20."""
    t1, t2, t3, t4, t5, t6 = theta
    w = np.array([-t5, t6])  # normal of the line: o3's velocity turned by −90°
    norm = float(np.hypot(*w))
    if norm == 0.0 or not math.isfinite(norm):
        raise DegenerateError("phase 1: object 3 does not move in the adaptive frame")
    p0 = t4 * w / norm**2
    u = np.array([t6, t5]) / norm
    qa = u[0] * u[1]
    qb = p0[0] * u[1] + p0[1] * u[0] - t2 * u[0] + t3 * u[1]
    qc = p0[0] * p0[1] - t2 * p0[0] + t3 * p0[1] - t1
    if abs(qa) <= 1e-12 * (abs(qb) + abs(qc) + 1e-300) / max(norm, 1.0):
        # o3 parallel to o1 or o2: the quadratic is linear, one root
        if qb == 0.0:
            raise DegenerateError("phase 1: objects 1–3 do not fix object 2's position")
        roots = [-qc / qb]
    else:
        disc = qb * qb - 4.0 * qa * qc
        if disc < 0.0:  # noise made a double root complex: take its real part
            disc = 0.0
        sq = math.sqrt(disc)
        roots = [(-qb + sq) / (2 * qa), (-qb - sq) / (2 * qa)]
    return [(float(p0[0] + s * u[0]), float(p0[1] + s * u[1])) for s in roots]


def closed_form(times: np.ndarray) -> Phase1Solution:
    """Phase 1 (paper 003 §5.1, eqs. 9–20) from ``times`` (m × 4, s): m ≥ 6 sensors' detection
    times of objects o1…o4; o1…o3 must be detected by every row, o4 by at least five (NaN =
    missed). With exactly six sensors the fit of o1…o3 is exact (eq. 5 is zero whatever the noise);
    with more, eq. 18 is solved in the least-squares sense (smallest singular vector).

    Raises :class:`DegenerateError` with the reason when the input cannot be solved: o1 or o2
    parallel to each other or to a beam, all beams parallel, or o4 fitting neither root."""
    t = np.asarray(times, dtype=float)
    if t.ndim != 2 or t.shape[1] != PHASE1_OBJECTS:
        raise ValueError(f"phase 1 needs an m × 4 array of detection times, got shape {t.shape}")
    if t.shape[0] < PHASE1_SENSORS:
        raise DegenerateError(f"phase 1 needs {PHASE1_SENSORS} sensors, got {t.shape[0]}")
    if not np.all(np.isfinite(t[:, :3])):
        raise DegenerateError("phase 1: every sensor must detect objects 1–3")
    seen4 = np.isfinite(t[:, 3])
    if seen4.sum() < SIGN_DETECTIONS:
        raise DegenerateError(f"phase 1: object 4 needs {SIGN_DETECTIONS} detections to choose the root of eq. 20")
    span = np.ptp(t[:, :3], axis=0)
    if np.any(span <= 0):
        raise DegenerateError("phase 1: an object met every beam at the same instant")
    # all beams parallel ⇔ every object's times are one affine function of the others
    e = np.ones(len(t))
    centred = np.column_stack([e] + [(c - c.mean()) / np.ptp(c) for c in t[:, :3].T])
    sv = np.linalg.svd(centred, compute_uv=False)
    if sv[2] <= RANK_RTOL * sv[0]:
        raise DegenerateError("phase 1: the beams are parallel (detection times affinely dependent)")

    # o1's reference time lies before any beam by one span, so no beam passes through the origin
    t_origin = float(t[:, 0].min() - span[0])
    t_refs = np.array([t_origin] + [float(np.nanmean(c)) for c in t[:, 1:].T])
    tau1, tau2, tau3 = (t[:, j] - t_refs[j] for j in range(3))
    m = np.column_stack([e, tau1, tau2, tau3, tau1 * tau3, tau2 * tau3, tau1 * tau2])  # eq. 17
    v = _null_vector(m, "phase 1 (eq. 18)")
    if abs(v[6]) <= 1e-9 * np.abs(v).max():
        raise DegenerateError("phase 1: objects 1 and 2 are parallel (eq. 18 has no solution with α5 = 1)")
    theta = v[:6] / v[6]

    tau4 = t[seen4, 3] - t_refs[3]
    best = None
    roots, residuals = [], []
    for x2, y2 in _phase1_candidates(theta):
        try:
            lines = np.array([line_through((p, 0.0), (x2, y2 + q)) for p, q in zip(tau1, tau2)])
            c3 = np.array([-theta[2], y2 - theta[1]])
            v3 = np.array([-theta[5], -theta[4]])
            c4, v4 = fit_object(lines[seen4], tau4, 0.0)
        except DegenerateError:
            continue
        pred = predicted_times(lines[seen4], c4, v4, 0.0)
        rms = float(np.sqrt(np.mean((pred - tau4) ** 2)))
        if not math.isfinite(rms):
            continue
        roots.append((x2, y2))
        residuals.append(rms)
        if best is None or rms < best[0]:
            best = (rms, len(roots) - 1, lines, c3, v3, c4, v4, (x2, y2))
    if best is None:
        raise DegenerateError("phase 1: no root of eq. 20 gives beams (objects 1 and 2 parallel?)")
    rms, chosen, lines, c3, v3, c4, v4, (x2, y2) = best
    if rms > CONSISTENCY_RTOL * np.ptp(tau4):
        raise DegenerateError(
            f"phase 1: object 4 fits neither root of eq. 20 (RMS time residual {rms:.3g} s; "
            "objects 1 and 2 parallel, or not straight passes?)")
    centres = np.array([[0.0, 0.0], [x2, y2], c3, c4])
    velocities = np.array([[1.0, 0.0], [0.0, 1.0], v3, v4])
    return Phase1Solution(lines, centres, velocities, t_refs, t_origin, tuple(roots), tuple(residuals), chosen)


# --------------------------------------------------------------------------- phase 2


class AdaptiveBasis:
    """The estimator of phases 1–2 for ``sensors`` line sensors (paper 003 §5).

    Feed objects one at a time with :meth:`add_object` (each a vector of the sensors' detection
    times, NaN where a sensor missed it — woke too late, or its beam lies outside the object's
    track). :meth:`try_initialise` runs phase 1 on the first four objects (in order) that allow it;
    from then on each :meth:`add_object` estimates the new object and runs ``iterations``
    block-coordinate Newton iterations (eqs. 23–26) on every sensor and object. Objects and sensors
    with too few known measurements to fix them wait until they have enough (an object needs four
    detections by estimated beams, a sensor two detections of estimated objects).

    The view Ω (eq. 21) is :attr:`omega`: which detection times this estimator knows. A node that
    knows only some measurements runs its own instance fed with those.
    """

    def __init__(self, sensors: int, *, iterations: int = DEFAULT_ITERATIONS, phase2: str = "lsq"):
        if sensors < 1:
            raise ValueError("the adaptive basis needs at least one sensor")
        if iterations < 0:
            raise ValueError(f"iterations must be ≥ 0, got {iterations}")
        if phase2 not in PHASE2_METHODS:
            raise ValueError(f"phase2 must be one of {', '.join(PHASE2_METHODS)}, got {phase2!r}")
        self.sensors = sensors
        self.iterations = iterations
        self.phase2 = phase2
        self.last_solve: SolveReport | None = None
        self._cols: list[np.ndarray] = []
        self.times = np.empty((sensors, 0))
        self.t_refs = np.empty(0)
        self.lines = np.full((sensors, 2), np.nan)
        self.centres = np.empty((0, 2))
        self.velocities = np.empty((0, 2))
        self.phase1: Phase1Solution | None = None
        self.phase1_objects: tuple[int, int, int, int] | None = None
        self.gauge: tuple[int, int] | None = None  # (o1, o2) of the adaptive frame
        self._searched = 0

    # ---------------------------------------------------------------- data

    @property
    def objects(self) -> int:
        return self.times.shape[1]

    @property
    def omega(self) -> np.ndarray:
        """Ω (eq. 21) as a sensors × objects boolean array: True where t_kl is known."""
        return np.isfinite(self.times)

    @property
    def initialised(self) -> bool:
        return self.phase1 is not None

    def line_known(self) -> np.ndarray:
        return np.all(np.isfinite(self.lines), axis=1)

    def object_known(self) -> np.ndarray:
        return np.all(np.isfinite(self.velocities), axis=1)

    def add_object(self, times: Iterable[float]) -> int:
        """Add the next object's detection times (s, length ``sensors``, NaN = not detected);
        after phase 1, estimate it and update everything (phase 2). Returns its index."""
        col = np.asarray(list(times), dtype=float).reshape(-1)
        if col.shape != (self.sensors,):
            raise ValueError(f"expected {self.sensors} detection times, got {col.shape[0]}")
        col = np.where(np.isfinite(col), col, np.nan)
        self.times = np.column_stack([self.times, col]) if self.objects else col[:, None].copy()
        seen = col[np.isfinite(col)]
        self.t_refs = np.append(self.t_refs, float(seen.mean()) if len(seen) else 0.0)
        self.centres = np.vstack([self.centres, np.full((1, 2), np.nan)])
        self.velocities = np.vstack([self.velocities, np.full((1, 2), np.nan)])
        index = self.objects - 1
        if self.initialised:
            self._object_step(np.array([index]))
            self.refine()
        return index

    # ---------------------------------------------------------------- phase 1

    def phase1_candidates(self) -> Iterable[tuple[int, int, int, int]]:
        """Object quadruples (o1 < o2 < o3 < o4) not tried yet whose coverage allows phase 1: six
        sensors detected o1, o2 and o3, and five of them o4; all four within
        :data:`PHASE1_WINDOW` consecutive objects (so that the search stays small however long
        phase 1 waits). In order: the earliest first."""
        seen = self.omega
        for last in range(max(self._searched, PHASE1_OBJECTS - 1), self.objects):
            first = max(0, last - PHASE1_WINDOW + 1)
            for triple in itertools.combinations(range(first, last), PHASE1_OBJECTS - 1):
                common = seen[:, triple[0]] & seen[:, triple[1]] & seen[:, triple[2]]
                if common.sum() >= PHASE1_SENSORS and (common & seen[:, last]).sum() >= SIGN_DETECTIONS:
                    yield (*triple, last)

    def try_initialise(self) -> bool:
        """Run phase 1 on the first quadruple of objects that solves (degenerate ones are skipped),
        then estimate every other object and sensor and iterate. False if none solves yet."""
        if self.initialised:
            return True
        for quad in self.phase1_candidates():
            try:
                self.initialise(quad)
                break
            except DegenerateError:
                continue
        self._searched = self.objects
        return self.initialised

    def initialise(self, quad: tuple[int, int, int, int]) -> Phase1Solution:
        """Phase 1 on objects ``quad`` (o1, o2, o3, o4) and the sensors that detected o1–o3;
        raises DegenerateError if they cannot be solved."""
        seen = self.omega
        rows = np.flatnonzero(seen[:, quad[0]] & seen[:, quad[1]] & seen[:, quad[2]])
        sol = closed_form(self.times[np.ix_(rows, quad)])
        self.lines[rows] = sol.lines
        for j, obj in enumerate(quad):
            # the solution's centres are at its reference times; move them to ours
            self.centres[obj] = sol.centres[j] + sol.velocities[j] * (self.t_refs[obj] - sol.t_refs[j])
            self.velocities[obj] = sol.velocities[j]
        self.phase1 = sol
        self.phase1_objects = tuple(int(q) for q in quad)
        self.gauge = (int(quad[0]), int(quad[1]))
        self._object_step(np.arange(self.objects))
        self.refine()
        return sol

    # ---------------------------------------------------------------- phase 2

    def refine(self) -> None:
        """Phase 2 after a new object (or phase 1): ``phase2 = "paper"`` runs :attr:`iterations`
        block-coordinate Newton iterations (§7.2); ``"lsq"`` (default) solves eq. 5 over every
        known measurement to its least-squares optimum (:meth:`solve`)."""
        if self.phase2 == "paper":
            self.iterate(self.iterations)
        else:
            self.solve()

    def _start_unknown(self) -> None:
        """Estimate the sensors and objects that have just got enough data to be fixed (one
        block Newton step on each, from zero: their exact least-squares block fit)."""
        unknown = ~self.line_known()
        if unknown.any():
            self._line_step(unknown)
        unknown = np.flatnonzero(~self.object_known())
        if len(unknown):
            self._object_step(unknown)

    def _layout(self) -> "_Problem":
        """The free parameters and known measurements of eq. 5 at the current estimate."""
        m, n = self.sensors, self.objects
        lk, ok = self.line_known(), self.object_known()
        mask = self.omega & lk[:, None] & ok[None, :]
        free = np.zeros((n, OBJECT_UNKNOWNS), dtype=bool)
        free[ok] = True
        if self.gauge is not None:  # the adaptive frame: o1 fixed, o2's velocity fixed
            free[self.gauge[0]] = False
            free[self.gauge[1], [0, 2]] = False
        rows = np.flatnonzero(lk)
        line_col = np.full((m, LINE_UNKNOWNS), -1)
        line_col[rows] = np.arange(LINE_UNKNOWNS * len(rows)).reshape(-1, LINE_UNKNOWNS)
        obj_col = np.full((n, OBJECT_UNKNOWNS), -1)
        obj_col[free] = LINE_UNKNOWNS * len(rows) + np.arange(int(free.sum()))
        k, l = np.nonzero(mask)
        w = np.column_stack([self.velocities[:, 0], self.centres[:, 0], self.velocities[:, 1], self.centres[:, 1]])
        return _Problem(rows, free, line_col, obj_col, k, l, self.times[k, l] - self.t_refs[l], w)

    def _store(self, problem: "_Problem", x: np.ndarray) -> None:
        lines, w = problem.unpack(x, self.lines)
        self.lines = lines
        self.velocities[:, 0], self.centres[:, 0] = w[:, 0], w[:, 1]
        self.velocities[:, 1], self.centres[:, 1] = w[:, 2], w[:, 3]

    def solve(self, *, xtol: float = SOLVE_XTOL, max_nfev: int | None = SOLVE_MAX_NFEV,
              joint: bool = False) -> "SolveReport":
        """Eq. 5 to its least-squares optimum over every known measurement (Ω, eq. 21) of the
        estimated sensors and objects, in the adaptive frame (o1 fixed, o2's velocity fixed), by
        ``scipy.optimize.least_squares`` (Levenberg–Marquardt, analytic Jacobian), warm-started
        from the current estimate until the relative step is below ``xtol``.

        Default: variable projection — the unknowns are the beams only; for given beams each
        object's (vx, cx, vy, cy) is its exact linear least-squares fit (eq. 5 is linear in them),
        and the Jacobian is Kaufman's (the beams' columns of eq. 24 projected off each object's
        columns), whose gradient Jᵀr is exact at the objects' optimum, so the stationary point is
        that of eq. 5. An evaluation costs O(measurements) and the unknowns stay 2·sensors, so a
        solve's cost grows linearly with the passes. ``joint=True``: the same problem over the
        beams and objects together (dense, for comparison; its cost grows cubically).

        Sensors and objects that have just got enough data are estimated first. Returns (and
        keeps in :attr:`last_solve`) the cost before and after, ‖Jᵀr‖ of the full problem after,
        and the number of evaluations."""
        from scipy.optimize import least_squares

        self._start_unknown()
        problem = self._layout()
        x_full = problem.pack(self.lines)
        before = float(np.sum(problem.residuals(x_full) ** 2))
        if len(problem.rows) == 0 or len(problem.k) < len(x_full) + 1:
            self.last_solve = SolveReport(before, before, 0.0, 0, len(problem.k), len(x_full))
            return self.last_solve
        if joint:
            res = least_squares(problem.residuals, x_full, jac=lambda x: problem.jacobian(x).toarray(),
                                method="lm", x_scale="jac", xtol=xtol, ftol=SOLVE_FTOL, gtol=SOLVE_GTOL,
                                max_nfev=max_nfev)
            candidate = res.x
        else:
            vp = _Projected(problem)
            res = least_squares(vp.residuals, vp.start(x_full), jac=vp.jacobian, method="lm", x_scale="jac",
                                xtol=xtol, ftol=SOLVE_FTOL, gtol=SOLVE_GTOL, max_nfev=max_nfev)
            candidate = vp.full(res.x)
        after = float(np.sum(problem.residuals(candidate) ** 2))
        if after <= before:  # never accept a worse point
            self._store(problem, candidate)
        else:
            after = before
        self.last_solve = SolveReport(before, after, self.gradient_norm(), int(res.nfev), len(problem.k),
                                      len(x_full))
        return self.last_solve

    def gradient_norm(self) -> float:
        """‖∇J‖/2 = ‖Jᵀr‖ of eq. 5 over the free parameters at the current estimate (0 at an optimum)."""
        problem = self._layout()
        x = problem.pack(self.lines)
        return float(np.linalg.norm(problem.jacobian(x).T @ problem.residuals(x)))

    def object_covariance(self, objects: Sequence[int] | None = None) -> np.ndarray:
        """Covariance of each object's (vx, cx, vy, cy) (its centre at its reference time) in the
        adaptive frame, relative to o1 and o2: the object blocks of :meth:`covariance`. Shape
        (len(objects), 4, 4); NaN for objects not estimated or without redundancy; the gauge's
        fixed components have zero variance."""
        objs = list(range(self.objects)) if objects is None else [int(o) for o in objects]
        out = np.full((len(objs), OBJECT_UNKNOWNS, OBJECT_UNKNOWNS), np.nan)
        known = self.object_known()
        for i, obj in enumerate(objs):
            if known[obj]:
                cov = self.covariance([obj], beams=False)
                if cov is not None:
                    out[i] = cov
        return out

    def covariance(self, objects: Sequence[int], *, beams: bool = True) -> np.ndarray | None:
        """Joint covariance s²·(JᵀJ)⁻¹ of eq. 5 at the current estimate (s² = J/(measurements −
        parameters)) of the beams (a, b) of every sensor (2·sensors rows, if ``beams``; zero for
        beams not estimated) and of ``objects``' (vx, cx, vy, cy) (4 rows each; zero for the
        adaptive frame's fixed components), in that order. Blocks of the inverse come from the
        Schur complement on the beams, so the cost is linear in the number of objects. None if
        there is no redundancy or an object in ``objects`` is not estimated."""
        problem = self._layout()
        objs = [int(o) for o in objects]
        x = problem.pack(self.lines)
        dof = len(problem.k) - len(x)
        known = self.object_known()
        if dof <= 0 or len(problem.rows) == 0 or not all(known[o] for o in objs):
            return None
        r = problem.residuals(x)
        s2 = float(r @ r) / dof
        mask = np.zeros(self.times.shape, dtype=bool)
        mask[problem.k, problem.l] = True
        tau = np.where(mask, self.times - self.t_refs, 0.0)
        free = problem.free
        lines = np.where(np.isfinite(self.lines), self.lines, 0.0)
        a, b = lines[:, :1], lines[:, 1:]
        ones = np.ones_like(tau)
        dfree = np.where(mask[..., None], np.stack([a * tau, a * ones, b * tau, b * ones], -1), 0.0) * free[None]
        w = np.where(np.isfinite(problem.w), problem.w, 0.0)
        jb = np.where(mask[..., None], np.stack([w[:, 1] + w[:, 0] * tau, w[:, 3] + w[:, 2] * tau], -1), 0.0)
        jb, dfb = jb[problem.rows], dfree[problem.rows]  # known sensors only: L × n × …
        hoo = np.einsum("kni,knj->nij", dfree, dfree)
        hoo[:, np.arange(4), np.arange(4)] += ~free  # fixed components: identity, no coupling
        cross = np.einsum("knj,knc->nkjc", jb, dfb).reshape(self.objects, -1, OBJECT_UNKNOWNS)  # H_bo per object
        nl = len(problem.rows)
        hbb = np.zeros((nl, LINE_UNKNOWNS, nl, LINE_UNKNOWNS))
        hbb[np.arange(nl), :, np.arange(nl), :] = np.einsum("kni,knj->kij", jb, jb)
        try:
            hoo_inv = np.linalg.inv(hoo)
            schur_inv = np.linalg.inv(hbb.reshape(nl * LINE_UNKNOWNS, -1)
                                      - np.einsum("npc,ncd,nqd->pq", cross, hoo_inv, cross))
        except np.linalg.LinAlgError:
            return None
        left = [hoo_inv[o] @ cross[o].T for o in objs]  # Hoo⁻¹·H_ob per object
        blocks_b = [-schur_inv @ lo.T for lo in left]  # Cov(beams, object)
        size = LINE_UNKNOWNS * self.sensors if beams else 0
        out = np.zeros((size + OBJECT_UNKNOWNS * len(objs),) * 2)
        cols = (LINE_UNKNOWNS * problem.rows[:, None] + np.arange(LINE_UNKNOWNS)).ravel()
        if beams:
            out[np.ix_(cols, cols)] = schur_inv
        for i, oi in enumerate(objs):
            si = slice(size + 4 * i, size + 4 * i + 4)
            if beams:
                out[cols, si] = blocks_b[i]
                out[si, cols] = blocks_b[i].T
            for j, oj in enumerate(objs):
                block = left[i] @ schur_inv @ left[j].T + (hoo_inv[oi] if i == j else 0.0)
                out[si, size + 4 * j:size + 4 * j + 4] = block
        # the frame's fixed components: no variance, no covariance
        fixed = np.concatenate([np.zeros(size, dtype=bool)] + [~free[o] for o in objs])
        out[fixed, :] = 0.0
        out[:, fixed] = 0.0
        return s2 * out

    def iterate(self, iterations: int = 1) -> list[float]:
        """``iterations`` block-coordinate Newton iterations (eq. 26 and its object analogue): a
        step on every sensor's (a, b) (rows of Ω), then on every object's (vx, x0, vy, y0)
        (columns of Ω), each with the blocks that have enough data. Returns the cost (eq. 5)
        after each iteration; it never increases."""
        costs = []
        for _ in range(iterations):
            self._line_step()
            self._object_step(np.arange(self.objects))
            costs.append(self.cost())
        return costs

    def _line_step(self, only: np.ndarray | None = None) -> None:
        """Newton step (eqs. 25–26) for every sensor (of the boolean mask ``only``, default all)
        with two known detections of estimated objects: (a, b) ← (a, b) − H⁻¹g with
        A = vx·t + x0, B = vy·t + y0."""
        known = self.object_known()
        tau = self.times - self.t_refs  # per-object local time (s)
        mask = self.omega & known[None, :]
        A = np.where(mask, self.centres[:, 0] + self.velocities[:, 0] * np.where(mask, tau, 0.0), 0.0)
        B = np.where(mask, self.centres[:, 1] + self.velocities[:, 1] * np.where(mask, tau, 0.0), 0.0)
        H = np.stack([np.stack([(A * A).sum(1), (A * B).sum(1)], -1),
                      np.stack([(A * B).sum(1), (B * B).sum(1)], -1)], -2)
        current = np.where(np.isfinite(self.lines), self.lines, 0.0)
        resid = np.where(mask, A * current[:, :1] + B * current[:, 1:] - 1.0, 0.0)
        g = np.stack([(resid * A).sum(1), (resid * B).sum(1)], -1)
        ok = (mask.sum(1) >= LINE_UNKNOWNS) & _well_conditioned(H)
        if only is not None:
            ok &= only
        if ok.any():
            self.lines[ok] = current[ok] - np.linalg.solve(H[ok], g[ok][..., None])[..., 0]

    def _object_step(self, objects: np.ndarray) -> None:
        """Newton step for each of ``objects`` on (vx, x0, vy, y0) with the rows D = a·t, C = a,
        F = b·t, E = b of eq. 24; o1 is fixed, o2 only moves its position (the adaptive frame)."""
        lk = self.line_known()
        lines = np.where(lk[:, None], self.lines, 0.0)
        tau = self.times[:, objects] - self.t_refs[objects]
        mask = np.isfinite(tau) & lk[:, None]
        tau = np.where(mask, tau, 0.0)
        a, b = lines[:, :1], lines[:, 1:]
        rows = np.stack([a * tau, a * np.ones_like(tau), b * tau, b * np.ones_like(tau)], -1)  # k × n × 4
        rows = np.where(mask[..., None], rows, 0.0)
        w = np.stack([self.velocities[objects, 0], self.centres[objects, 0],
                      self.velocities[objects, 1], self.centres[objects, 1]], -1)
        w = np.where(np.isfinite(w), w, 0.0)
        free = np.ones((len(objects), 4), dtype=bool)
        if self.gauge is not None:
            free[objects == self.gauge[0]] = False
            free[objects == self.gauge[1], 0] = False
            free[objects == self.gauge[1], 2] = False
            g2 = objects == self.gauge[1]
            w[g2, 0], w[g2, 2] = 0.0, 1.0
            g1 = objects == self.gauge[0]
            w[g1] = [1.0, self.t_refs[self.gauge[0]] - self.phase1.t_origin, 0.0, 0.0]
        resid = np.where(mask, np.einsum("knc,nc->kn", rows, w) - 1.0, 0.0)
        grad = np.einsum("kn,knc->nc", resid, rows)
        H = np.einsum("kni,knj->nij", rows, rows)
        # fixed parameters: identity rows, zero gradient
        fixed = ~free
        H = np.where(fixed[:, :, None] | fixed[:, None, :], 0.0, H)
        H[:, np.arange(4), np.arange(4)] += fixed
        grad = np.where(fixed, 0.0, grad)
        need = free.sum(1)
        ok = (mask.sum(0) >= need) & _well_conditioned(H)
        w_new = w.copy()
        if ok.any():
            w_new[ok] = w[ok] - np.linalg.solve(H[ok], grad[ok][..., None])[..., 0]
        sel = objects[ok]
        self.velocities[sel, 0], self.centres[sel, 0] = w_new[ok, 0], w_new[ok, 1]
        self.velocities[sel, 1], self.centres[sel, 1] = w_new[ok, 2], w_new[ok, 3]

    # ---------------------------------------------------------------- results

    def cost(self) -> float:
        """J of eq. 5 over the known measurements with an estimated sensor and object."""
        tau = self.times - self.t_refs
        mask = self.omega & self.line_known()[:, None] & self.object_known()[None, :]
        if not mask.any():
            return 0.0
        tau = np.where(mask, tau, 0.0)
        px = self.centres[:, 0] + self.velocities[:, 0] * tau
        py = self.centres[:, 1] + self.velocities[:, 1] * tau
        r = np.where(mask, self.lines[:, :1] * px + self.lines[:, 1:] * py - 1.0, 0.0)
        return float((r * r).sum())

    def time_residuals(self) -> np.ndarray:
        """Measured minus predicted detection time (s) per known measurement (NaN elsewhere)."""
        out = np.full(self.times.shape, np.nan)
        for obj in np.flatnonzero(self.object_known()):
            rows = np.flatnonzero(self.omega[:, obj] & self.line_known())
            pred = predicted_times(self.lines[rows], self.centres[obj], self.velocities[obj], self.t_refs[obj])
            out[rows, obj] = self.times[rows, obj] - pred
        return out

    def object_parameters(self) -> np.ndarray:
        """(vx, x0, vy, y0) of every object (eq. 2; x0, y0 at time 0 of the data's clock), in the
        adaptive frame; NaN rows for objects not estimated yet."""
        x0 = self.centres - self.velocities * self.t_refs[:, None]
        return np.column_stack([self.velocities[:, 0], x0[:, 0], self.velocities[:, 1], x0[:, 1]])

    def position(self, obj: int, t) -> np.ndarray:
        """Adaptive-frame position(s) of object ``obj`` at time(s) ``t`` (s), shape t.shape + (2,)."""
        t = np.asarray(t, dtype=float)
        return self.centres[obj] + self.velocities[obj] * (t - self.t_refs[obj])[..., None]


@dataclass(frozen=True)
class SolveReport:
    """One :meth:`AdaptiveBasis.solve`: cost J (eq. 5) before and after, ‖Jᵀr‖ after, function
    evaluations, measurements and free parameters."""

    cost_before: float
    cost: float
    gradient: float
    evaluations: int
    measurements: int
    parameters: int


@dataclass(frozen=True)
class _Problem:
    """Eq. 5 as a least-squares problem in the free parameters: the estimated beams (a, b) of
    sensors ``rows``, then the free components of each object's w = (vx, cx, vy, cy) (``free``);
    measurements (sensor ``k``, object ``l``) at local times ``tau`` (s); ``w`` the current
    object parameters (the fixed components are taken from it)."""

    rows: np.ndarray
    free: np.ndarray
    line_col: np.ndarray
    obj_col: np.ndarray
    k: np.ndarray
    l: np.ndarray
    tau: np.ndarray
    w: np.ndarray

    def pack(self, lines: np.ndarray) -> np.ndarray:
        return np.concatenate([lines[self.rows].ravel(), self.w[self.free]])

    def unpack(self, x: np.ndarray, lines: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        nb = LINE_UNKNOWNS * len(self.rows)
        lines = lines.copy()
        lines[self.rows] = x[:nb].reshape(-1, LINE_UNKNOWNS)
        w = self.w.copy()
        w[self.free] = x[nb:]
        return lines, w

    def _parts(self, x: np.ndarray):
        nb = LINE_UNKNOWNS * len(self.rows)
        ab = np.zeros((len(self.line_col), LINE_UNKNOWNS))
        ab[self.rows] = x[:nb].reshape(-1, LINE_UNKNOWNS)
        w = self.w.copy()
        w[self.free] = x[nb:]
        a, b = ab[self.k, 0], ab[self.k, 1]
        wl = w[self.l]
        return a, b, wl[:, 1] + wl[:, 0] * self.tau, wl[:, 3] + wl[:, 2] * self.tau

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """τ_kl of eq. 4 per known measurement."""
        a, b, A, B = self._parts(x)
        return a * A + b * B - 1.0

    def jacobian(self, x: np.ndarray):
        """∂τ_kl/∂(a_k, b_k) = (A, B) and ∂τ_kl/∂(vx, cx, vy, cy)_l = (a·t, a, b·t, b) (eq. 24), sparse."""
        from scipy.sparse import csr_matrix

        a, b, A, B = self._parts(x)
        n = len(self.k)
        vals = np.column_stack([A, B, a * self.tau, a, b * self.tau, b])
        cols = np.column_stack([self.line_col[self.k], self.obj_col[self.l]])
        rows = np.repeat(np.arange(n), cols.shape[1]).reshape(n, -1)
        keep = cols >= 0
        size = LINE_UNKNOWNS * len(self.rows) + int(self.free.sum())
        return csr_matrix((vals[keep], (rows[keep], cols[keep])), shape=(n, size))


class _Projected:
    """Variable projection of a :class:`_Problem`: eq. 5 as a function of the beams alone, each
    object's free components at their least-squares optimum for those beams. Arrays are
    sensors × objects, zero outside the known measurements."""

    def __init__(self, problem: _Problem):
        self.p = problem
        m, n = len(problem.line_col), len(problem.w)
        self.mask = np.zeros((m, n), dtype=bool)
        self.mask[problem.k, problem.l] = True
        self.tau = np.zeros((m, n))
        self.tau[problem.k, problem.l] = problem.tau
        self.nb = LINE_UNKNOWNS * len(problem.rows)
        self.w = problem.w.copy()
        self._cache: tuple[bytes, tuple] | None = None

    def start(self, x_full: np.ndarray) -> np.ndarray:
        return x_full[:self.nb].copy()

    def _eval(self, beams: np.ndarray):
        key = beams.tobytes()
        if self._cache is not None and self._cache[0] == key:
            return self._cache[1]
        p, mask, tau = self.p, self.mask, self.tau
        ab = np.zeros((len(p.line_col), LINE_UNKNOWNS))
        ab[p.rows] = beams.reshape(-1, LINE_UNKNOWNS)
        a, b = ab[:, :1], ab[:, 1:]
        ones = np.ones_like(tau)
        design = np.where(mask[..., None], np.stack([a * tau, a * ones, b * tau, b * ones], -1), 0.0)  # m × n × 4
        free = p.free
        fixed = np.where(free, 0.0, np.where(np.isfinite(self.w), self.w, 0.0))
        y = np.where(mask, 1.0 - np.einsum("knc,nc->kn", design, fixed), 0.0)
        dfree = design * free[None, :, :]
        gram = np.einsum("kni,knj->nij", dfree, dfree)
        gram[:, np.arange(4), np.arange(4)] += ~free
        rhs = np.einsum("knc,kn->nc", dfree, y)
        try:
            inv = np.linalg.inv(gram)
        except np.linalg.LinAlgError:
            inv = np.linalg.pinv(gram)
        u = np.einsum("nij,nj->ni", inv, rhs)
        w = np.where(free, u, fixed)
        r = np.where(mask, np.einsum("knc,nc->kn", dfree, u) - y, 0.0)
        out = (ab, w, dfree, inv, r)
        self._cache = (key, out)
        return out

    def residuals(self, beams: np.ndarray) -> np.ndarray:
        return self._eval(beams)[4][self.p.k, self.p.l]

    def jacobian(self, beams: np.ndarray) -> np.ndarray:
        """Kaufman's Jacobian: ∂τ/∂(a_k, b_k) = (A, B) projected off each object's free columns."""
        ab, w, dfree, inv, _ = self._eval(beams)
        tau, mask = self.tau, self.mask
        jb = np.where(mask[..., None], np.stack([w[:, 1] + w[:, 0] * tau, w[:, 3] + w[:, 2] * tau], -1), 0.0)  # m × n × 2
        cross = np.einsum("knc,knj->nckj", dfree, jb)  # object l's Jₒᵀ·J_b, n × 4 × m × 2
        corr = np.einsum("knc,ncd,ndpj->knpj", dfree, inv, cross)  # m × n × m × 2
        m = len(ab)
        full = -corr
        idx = np.arange(m)
        full[idx, :, idx, :] += jb
        rows = full[self.p.k, self.p.l]  # measurements × m × 2
        return rows[:, self.p.rows, :].reshape(len(self.p.k), -1)

    def full(self, beams: np.ndarray) -> np.ndarray:
        """The full parameter vector (beams, then the objects' free components) at ``beams``."""
        _, w, *_ = self._eval(beams)
        return np.concatenate([beams, w[self.p.free]])


def _well_conditioned(H: np.ndarray) -> np.ndarray:
    """Per matrix of the stack ``H`` (n × k × k): invertible with a Jacobi-scaled condition number
    below :data:`COND_MAX`."""
    if H.shape[0] == 0:
        return np.zeros(0, dtype=bool)
    d = np.sqrt(np.abs(np.einsum("nii->ni", H)))
    ok = np.all(d > 0, axis=1)
    d = np.where(d > 0, d, 1.0)
    scaled = H / d[:, :, None] / d[:, None, :]
    with np.errstate(invalid="ignore", over="ignore"):
        cond = np.linalg.cond(scaled)
    return ok & np.isfinite(cond) & (cond < COND_MAX)


# --------------------------------------------------------------------------- phase 3


@dataclass(frozen=True)
class Frame:
    """The affine map x_adaptive = A·x_real + d of eq. 27 and what fixed it (``source``:
    "sensors" — known positions and/or beams, eqs. 28–30 — or "calibration" — known passes,
    §7.1 eqs. 32–33)."""

    A: np.ndarray
    d: np.ndarray
    source: str

    def points(self, xy) -> np.ndarray:
        """Adaptive points (…, 2) → real-world points, units."""
        return np.linalg.solve(self.A, (np.asarray(xy, dtype=float) - self.d).T).T

    def vectors(self, v) -> np.ndarray:
        """Adaptive velocities (…, 2) → real-world velocities, units/s."""
        return np.linalg.solve(self.A, np.asarray(v, dtype=float).T).T

    def lines(self, ab) -> np.ndarray:
        """Adaptive beams (a, b) (…, 2) → real-world beams (eq. 30): Aᵀ·n / (1 − n·d), units⁻¹."""
        n = np.asarray(ab, dtype=float)
        return (n @ self.A) / (1.0 - n @ self.d)[..., None]

    def objects(self, params) -> np.ndarray:
        """Adaptive (vx, x0, vy, y0) rows (n × 4) → real-world ones (units/s, units; same clock)."""
        p = np.asarray(params, dtype=float).reshape(-1, 4)
        v, x0 = self.vectors(p[:, [0, 2]]), self.points(p[:, [1, 3]])
        return np.column_stack([v[:, 0], x0[:, 0], v[:, 1], x0[:, 1]])


def _affine_unknowns(rows: list[np.ndarray], rhs: list[float], source: str, what: str) -> Frame:
    m = np.array(rows, dtype=float).reshape(-1, 6)
    y = np.array(rhs, dtype=float)
    if len(m) < 6:
        raise DegenerateError(f"{what}: {len(m)} equations cannot fix the 6 unknowns of eq. 27")
    norm = np.linalg.norm(m, axis=1)
    norm[norm == 0] = 1.0
    u = _lstsq_rank(m / norm[:, None], y / norm, f"{what}: they do not fix the frame")
    A = u[:4].reshape(2, 2)
    if abs(np.linalg.det(A)) <= 1e-12 * float(np.abs(A).max()) ** 2:
        raise DegenerateError(f"{what}: the fitted map is singular")
    return Frame(A, u[4:].copy(), source)


def frame_from_sensors(lines: np.ndarray, positions: Mapping[int, Sequence[float]] | None = None,
                       beams: Mapping[int, Sequence[float]] | None = None) -> Frame:
    """Phase 3 from sensors (§5.3): ``lines`` are the adaptive beams (m × 2); ``positions`` maps a
    sensor index to its real position (x, y) (one equation each, eqs. 28–29: a point of the beam);
    ``beams`` maps a sensor index to its real beam (a, b) (two equations each: Aᵀn = (1 − n·d)·n_real).
    Six positions in general position suffice; collinear positions do not (DegenerateError)."""
    rows, rhs = [], []
    for k, (px, py) in (positions or {}).items():
        nx, ny = lines[k]
        rows.append([nx * px, nx * py, ny * px, ny * py, nx, ny])
        rhs.append(1.0)
    for k, (ra, rb) in (beams or {}).items():
        nx, ny = lines[k]
        rows.append([nx, 0.0, ny, 0.0, nx * ra, ny * ra])
        rhs.append(ra)
        rows.append([0.0, nx, 0.0, ny, nx * rb, ny * rb])
        rhs.append(rb)
    if rows and not np.all(np.isfinite(np.array(rows))):
        raise DegenerateError("sensor positions: a sensor's beam is not estimated")
    return _affine_unknowns(rows, rhs, "sensors", "known sensor positions/beams")


def frame_from_points(pairs: Iterable[tuple[Sequence[float], Sequence[float]]]) -> Frame:
    """Phase 3 from known trajectories (§7.1, eqs. 32–33): ``pairs`` of (adaptive point, real
    point) — e.g. each calibration pass's entry and exit, the adaptive points being the estimated
    pass at the given times. Two non-parallel passes (four points) fix the frame."""
    rows, rhs = [], []
    for (qx, qy), (px, py) in pairs:
        rows.append([px, py, 0.0, 0.0, 1.0, 0.0])
        rhs.append(qx)
        rows.append([0.0, 0.0, px, py, 0.0, 1.0])
        rhs.append(qy)
    return _affine_unknowns(rows, rhs, "calibration", "calibration passes")


def collinear(points: Sequence[Sequence[float]], rtol: float = 1e-3) -> bool:
    """Whether ``points`` (units) lie on one line (or fewer than three distinct points): the smaller
    principal spread is below ``rtol`` of the larger."""
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(p) < 3:
        return True
    s = np.linalg.svd(p - p.mean(0), compute_uv=False)
    return bool(s[0] == 0 or s[1] <= rtol * s[0])


# --------------------------------------------------------------------------- results in the region


def border_times(centre: Sequence[float], velocity: Sequence[float], t_ref: float,
                 box: tuple[float, float, float, float]) -> tuple[float, float] | None:
    """Times (s) at which the straight pass p(t) = centre + velocity·(t − t_ref) enters and leaves
    the rectangle ``box`` = (xmin, ymin, xmax, ymax); None if the line misses it."""
    lo, hi = -math.inf, math.inf
    for axis, (bmin, bmax) in enumerate(((box[0], box[2]), (box[1], box[3]))):
        c, v = float(centre[axis]), float(velocity[axis])
        if v == 0.0:
            if not bmin <= c <= bmax:
                return None
            continue
        t1, t2 = (bmin - c) / v, (bmax - c) / v
        lo, hi = max(lo, min(t1, t2)), min(hi, max(t1, t2))
    if lo > hi or not (math.isfinite(lo) and math.isfinite(hi)):
        return None
    return t_ref + lo, t_ref + hi


def parameter_error(lines: np.ndarray, objects: np.ndarray, true_lines: np.ndarray, true_objects: np.ndarray) -> float:
    """Jp of eq. 31: the mean squared error over the 2m beam parameters (a, b) and the 4n object
    parameters (vx, x0, vy, y0), both in the same (real-world) frame and clock."""
    m, n = len(true_lines), len(true_objects)
    total = float(((np.asarray(lines) - true_lines) ** 2).sum() + ((np.asarray(objects) - true_objects) ** 2).sum())
    return total / (2 * m + 4 * n)


# --------------------------------------------------------------------------- the paper's simulation setup


@dataclass(frozen=True)
class PassageScene:
    """Paper 003 §6 (Fig. 5): line sensors across a passage [0, L] × [0, W] and straight passes
    entering at x = 0 and leaving at x = L. ``lines`` (m × 2) the true beams (a, b), units⁻¹;
    ``objects`` (n × 4) the true (vx, x0, vy, y0) — units/s and units, each object timed from its
    own entry (t = 0 at x = 0, so (x0, y0) is the entry point); ``times`` (m × n) detection times
    (s, eq. 3 plus noise); ``entries``/``exits`` (n × 2) the border points; ``durations`` (n,) s."""

    lines: np.ndarray
    objects: np.ndarray
    times: np.ndarray
    entries: np.ndarray
    exits: np.ndarray
    durations: np.ndarray

    def calibration_pairs(self, basis: "AdaptiveBasis", objects: Sequence[int] = (0, 1)):
        """(adaptive point, real point) pairs of the entries and exits of ``objects`` — the passes
        known in real-world coordinates (the paper fixes the first two) — for :func:`frame_from_points`."""
        pairs = []
        for obj in objects:
            pairs.append((basis.position(obj, 0.0), self.entries[obj]))
            pairs.append((basis.position(obj, self.durations[obj]), self.exits[obj]))
        return pairs


def passage_scene(rng: np.random.Generator, *, sensors: int = 6, objects: int = 4, noise: float = 0.01,
                  speeds: tuple[float, float] = (0.01, 0.1), length: float = 1.0, width: float = 1.0,
                  angles: tuple[float, float] = (60.0, 66.0)) -> PassageScene:
    """The simulation of paper 003 §6: ``sensors`` beams along the passage (the left half leaning
    right, the rest left, at ≈ 63° — the simulator's laser layout), ``objects`` passes at speeds
    U[speeds] (units/s), detection times with U[−noise, noise] s noise. Pass 1 runs along the
    bottom (0, 0) → (L, 0), pass 2 from (0, 0) to (L, W) (fixed, as in the paper, so that they are
    not parallel); the others enter and leave at uniform heights."""
    from bintrack.sim.deployments import laser_track

    beams = laser_track(rng, length, width, sensors, angles)
    lines = np.array([(s.a, s.b) for s in beams])
    entries = np.column_stack([np.zeros(objects), rng.uniform(0.0, width, objects)])
    exits = np.column_stack([np.full(objects, length), rng.uniform(0.0, width, objects)])
    fixed_exits = (0.0, width)  # pass 1 along the bottom, pass 2 to the top corner
    for k in range(min(2, objects)):
        entries[k, 1], exits[k, 1] = 0.0, fixed_exits[k]
    speed = rng.uniform(*speeds, objects)
    delta = exits - entries
    durations = np.hypot(*delta.T) / speed
    velocity = delta / durations[:, None]
    objs = np.column_stack([velocity[:, 0], entries[:, 0], velocity[:, 1], entries[:, 1]])
    times = (1.0 - lines @ entries.T) / (lines @ velocity.T)
    times = times + rng.uniform(-noise, noise, times.shape) if noise else times
    return PassageScene(lines, objs, times, entries, exits, durations)
