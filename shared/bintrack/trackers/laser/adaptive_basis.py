"""Phase 2 of the adaptive basis algorithm (paper 003 §5.2), the estimator that runs phases 1–2
as passes arrive (:class:`AdaptiveBasis`).

* **Phase 1** (§5.1, :mod:`.phase1_closed_form`): the adaptive frame and the first four passes
  in closed form.
* **Phase 2** (§5.2, here): as objects (and sensors) arrive, block-coordinate
  Newton steps on eq. 23 — per sensor on (a, b) (eqs. 24–26), per object on
  (vx, x0, vy, y0) — five iterations per pass by default. The cost is quadratic in each block, so
  each Newton step is that block's exact minimiser and the cost (eq. 5) never increases; or
  (default) eq. 5 solved to its least-squares optimum (:mod:`.phase2_least_squares`).
* **Phase 3** (§5.3, §7.1, :mod:`.phase3_frame`): the affine map to real-world coordinates.

The model and units: :mod:`.line_model`. Everything here is pure numpy: deterministic, no I/O.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Sequence

import numpy as np

from bintrack.trackers.laser.line_model import (
    LINE_UNKNOWNS,
    OBJECT_UNKNOWNS,
    DegenerateError,
    predicted_times,
    well_conditioned,
)
from bintrack.trackers.laser.phase1_closed_form import (
    PHASE1_OBJECTS,
    PHASE1_SENSORS,
    PHASE1_WINDOW,
    SIGN_DETECTIONS,
    Phase1Solution,
    closed_form,
)
from bintrack.trackers.laser.phase2_least_squares import LeastSquaresProblem, SolveReport, VariableProjection

DEFAULT_ITERATIONS = 5  # §7.2: "The number of iterations of Newton's method was fixed to 5"
PHASE2_METHODS = ("lsq", "paper")
SOLVE_XTOL = 1e-10  # relative step at which the least-squares phase 2 stops
SOLVE_FTOL = 1e-15
SOLVE_GTOL = 1e-15
SOLVE_MAX_NFEV: int | None = None


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

    def _layout(self) -> "LeastSquaresProblem":
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
        return LeastSquaresProblem(rows, free, line_col, obj_col, k, l, self.times[k, l] - self.t_refs[l], w)

    def _store(self, problem: "LeastSquaresProblem", x: np.ndarray) -> None:
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
            vp = VariableProjection(problem)
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
        ok = (mask.sum(1) >= LINE_UNKNOWNS) & well_conditioned(H)
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
        ok = (mask.sum(0) >= need) & well_conditioned(H)
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

