"""Phase 2's least-squares problem (paper 003 §5.2, eq. 5 over the view Ω of eq. 21): the
residuals and sparse Jacobian in the free parameters, its variable projection onto the beams
alone (Kaufman's Jacobian), and the report of one solve."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bintrack.trackers.laser.line_model import LINE_UNKNOWNS


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
class LeastSquaresProblem:
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


class VariableProjection:
    """Variable projection of a :class:`LeastSquaresProblem`: eq. 5 as a function of the beams alone, each
    object's free components at their least-squares optimum for those beams. Arrays are
    sensors × objects, zero outside the known measurements."""

    def __init__(self, problem: LeastSquaresProblem):
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
