"""The revised estimates (paper 003 §3 model, solved in real-world coordinates): every beam and
pass re-solved together from the detection times, once phases 1–3 have placed them.

Phase 2 minimises eq. 5's equation errors in the adaptive frame and phase 3 then fits the frame
to the calibration passes. Here the same model is solved directly where it is reported, by
maximum likelihood for independent timing errors of equal variance: minimise

    Σ_kl (t_kl − r_l − (1 − n_k·c_l)/(n_k·v_l))²            (eq. 3's time residuals)

over the real-world beams n_k = (a_k, b_k) and passes w_l = (vx, cx, vy, cy), with what the
deployment knows held exact: the calibration passes (their entry and exit points at their times
fix w_l), known beams, and known sensor positions (n_k·q_k = 1, so such a beam moves along one
direction). Started from phases 1–3's estimate. Variable projection over the beams (at most two
unknowns per beam): for given beams each pass is its own 4-unknown fit (eq. 5's linear fit, then
Gauss–Newton steps on the time residuals), and the beams' Jacobian is Kaufman's (their columns
projected off each pass's); an evaluation costs O(passes).

The covariance of the result is :func:`~.pass_bound.joint_covariances` at the estimate, scaled
by the residual variance. Pure numpy/scipy, deterministic, no I/O.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bintrack.trackers.laser.pass_bound import joint_covariances

INNER_STEPS = 3  # Gauss–Newton steps per pass and evaluation: from eq. 5's fit the step is already tiny
XTOL = 1e-10


@dataclass(frozen=True)
class RealWorldSolution:
    """Beams (m × 2, units⁻¹), passes (n × 4: vx, cx, vy, cy at ``t_refs``; NaN where not
    solved), residual variance s² (s²), and per pass its 4 × 4 covariance and the beams' share
    of it (what better beams could still change); zero for the ``fixed`` (exact) passes."""

    lines: np.ndarray
    passes: np.ndarray
    variance: float
    covariance: dict[int, np.ndarray]
    beam_share: dict[int, np.ndarray]


def _predict(n: np.ndarray, w: np.ndarray):
    """Predicted local times τ̂ (m × n), rates s = n·v, and ∂τ̂/∂w (m × n × 4)."""
    s = n[:, :1] * w[:, 0] + n[:, 1:] * w[:, 2]
    th = (1.0 - n[:, :1] * w[:, 1] - n[:, 1:] * w[:, 3]) / s
    a, b = n[:, :1] / s, n[:, 1:] / s
    return th, s, -np.stack([a * th, a, b * th, b], -1)


def fit_passes(n: np.ndarray, tau: np.ndarray, mask: np.ndarray, w: np.ndarray, free: np.ndarray) -> np.ndarray:
    """Each ``free`` pass's w minimising its time residuals for beams ``n``: eq. 5's linear fit
    weighted by 1/(n·v) of the current ``w``, then :data:`INNER_STEPS` Gauss–Newton steps."""
    w = w.copy()
    idx = np.flatnonzero(free)
    if not len(idx):
        return w
    t, mk = np.where(mask[:, idx], tau[:, idx], 0.0), mask[:, idx]
    s = np.abs(n[:, :1] * w[idx, 0] + n[:, 1:] * w[idx, 2])
    weight = np.where(mk, 1.0 / np.where(s > 0, s, 1.0), 0.0)
    a, b = n[:, :1] * weight, n[:, 1:] * weight
    design = np.stack([a * t, a, b * t, b], -1)
    gram = np.einsum("kni,knj->nij", design, design)
    rhs = np.einsum("kni,kn->ni", design, weight)
    w[idx] = np.linalg.solve(gram, rhs[..., None])[..., 0]
    for _ in range(INNER_STEPS):
        th, _, g = _predict(n, w[idx])
        g = np.where(mk[..., None], g, 0.0)
        r = np.where(mk, t - th, 0.0)
        step = np.linalg.solve(np.einsum("kni,knj->nij", g, g), np.einsum("kni,kn->ni", g, r)[..., None])[..., 0]
        w[idx] += step
    return w


class RealWorldProblem:
    """The time-residual problem over the beams' free directions (variable projection)."""

    def __init__(self, times: np.ndarray, t_refs: np.ndarray, lines: np.ndarray, passes: np.ndarray,
                 fixed: Sequence[int], directions: Sequence[np.ndarray]):
        self.mask = np.isfinite(times) & np.all(np.isfinite(passes), axis=1)[None, :]
        self.tau = np.where(self.mask, times - t_refs, 0.0)
        self.base, self.dirs = np.asarray(lines, dtype=float), list(directions)
        self.offsets = np.cumsum([0] + [d.shape[1] for d in self.dirs])
        self.free = np.all(np.isfinite(passes), axis=1)
        self.free[list(fixed)] = False
        self.w = np.where(np.isfinite(passes), passes, 0.0)
        self._cache: tuple[bytes, tuple] | None = None

    def lines(self, x: np.ndarray) -> np.ndarray:
        return self.base + np.stack([d @ x[self.offsets[k]:self.offsets[k + 1]] for k, d in enumerate(self.dirs)])

    def _eval(self, x: np.ndarray):
        key = x.tobytes()
        if self._cache is None or self._cache[0] != key:
            n = self.lines(x)
            w = fit_passes(n, self.tau, self.mask, self.w, self.free)
            self.w = w  # warm start for the next evaluation
            self._cache = (key, (n, w))
        return self._cache[1]

    def residuals(self, x: np.ndarray) -> np.ndarray:
        n, w = self._eval(x)
        th, _, _ = _predict(n, w)
        return (self.tau - th)[self.mask]

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """∂r/∂x with each free pass's columns projected out (Kaufman)."""
        n, w = self._eval(x)
        th, s, g = _predict(n, w)
        p = np.stack([w[:, 1] + w[:, 0] * th, w[:, 3] + w[:, 2] * th], -1)  # crossing points, m × n × 2
        jb = np.zeros(self.mask.shape + (int(self.offsets[-1]),))
        for k, d in enumerate(self.dirs):
            jb[k, :, self.offsets[k]:self.offsets[k + 1]] = (p[k] / s[k][:, None]) @ d  # −∂τ̂/∂n = p/s
        jb = np.where(self.mask[..., None], jb, 0.0)
        g = np.where((self.mask & self.free[None, :])[..., None], g, 0.0)
        gram = np.einsum("kni,knj->nij", g, g)
        gram[~self.free] = np.eye(4)
        coef = np.linalg.solve(gram, np.einsum("kni,knj->nij", g, jb))
        jb = jb - np.einsum("kni,nij->knj", g, coef)
        return jb[self.mask]


def solve_real_world(times: np.ndarray, t_refs: np.ndarray, lines: np.ndarray, passes: np.ndarray,
                     fixed: Sequence[int], directions: Sequence[np.ndarray]) -> RealWorldSolution | None:
    """Minimise the time residuals (module docstring) from the real-world estimate ``lines``
    (m × 2, each on its known position's constraint) and ``passes`` (n × 4 at ``t_refs``, NaN
    rows not solved); ``fixed`` passes are exact. None if the problem has no redundancy or is
    singular."""
    from scipy.optimize import least_squares

    problem = RealWorldProblem(times, t_refs, lines, passes, fixed, directions)
    unknowns = int(problem.offsets[-1]) + 4 * int(problem.free.sum())
    dof = int(problem.mask.sum()) - unknowns
    if dof <= 0:
        return None
    try:
        with np.errstate(all="ignore"):
            x0 = np.zeros(int(problem.offsets[-1]))
            if len(x0):
                res = least_squares(problem.residuals, x0, jac=problem.jacobian, method="lm", xtol=XTOL)
                x = res.x
            else:
                x = x0
            n, w = problem._eval(x)
            r = problem.residuals(x)
            variance = float(r @ r) / dof
            w = np.where(problem.mask.any(0)[:, None] & np.all(np.isfinite(passes), axis=1)[:, None], w, np.nan)
            total, share = joint_covariances(n, np.nan_to_num(w), problem.mask, 1.0, fixed, directions)
    except (np.linalg.LinAlgError, ValueError):  # singular, or not finite (a degenerate start)
        return None
    if not np.isfinite(variance):
        return None
    exact = {int(l): np.zeros((4, 4)) for l in fixed}
    scale = lambda d: {**exact, **{l: variance * c for l, c in d.items()}}  # noqa: E731
    return RealWorldSolution(n, w, variance, scale(total), scale(share))
