"""A reference solver for the tests of :mod:`bintrack.trackers.motion.svm_estimator`: the primal
QP of the (multi-period, shared-normal) SVM solved by SLSQP with chunking (Cortes & Vapnik
1995), slow but direct, against which the library's exact one-dimensional (hard margin) and
convex-in-w (soft margin) forms are checked."""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize

from bintrack.trackers.motion.svm_estimator import SvmResult, band_gaps, svm_problem


def svm_fit_qp(positions: np.ndarray, labels: np.ndarray, c: float = 1000.0, working: int = 6,
               max_rounds: int = 30) -> SvmResult | None:
    """The problem of :func:`~bintrack.trackers.motion.svm_estimator.svm_fit`, solved as its
    primal QP: min ½|w|² (+ ``c``·Σξ when not separable) by ``minimize(method="SLSQP")`` on a
    working set of ``working`` points per class and period nearest the current line, grown by
    every point that violates its margin until none does (at most ``max_rounds`` rounds);
    points left out have zero multipliers, so the solution is that of the whole problem. For
    the hard margin each b_k is centred in its period's empty band, as svm_fit does."""
    problem = svm_problem(positions, labels)
    if problem is None:
        return None
    z, lab = problem.z, problem.lab
    w, b = _svm_qp(z, lab, not problem.separable, c, working, max_rounds, problem.start)
    if problem.separable:
        lo, hi = band_gaps(z, lab, w)
        b = -(lo + hi) / 2
    return problem.result(w, b)


def _qp(z: list[np.ndarray], y: list[np.ndarray], soft: bool, c: float,
        start: np.ndarray) -> np.ndarray:
    """Solve min ½|w|² (+ C·Σξ) s.t. y_i (w·z_i + b_k) ≥ 1 (− ξ_i), ξ ≥ 0 over the given working
    sets (one per period) with SLSQP; variables [w (2), b (K), ξ (M if soft)]."""
    k = len(z)
    rows = np.concatenate([np.full(len(zk), n) for n, zk in enumerate(z)])
    zz = np.concatenate(z)
    yy = np.concatenate(y).astype(float)
    m = len(zz)
    nvar = 2 + k + (m if soft else 0)
    # constraint matrix A x ≥ 1 (linear)
    a = np.zeros((m, nvar))
    a[:, 0:2] = yy[:, None] * zz
    a[np.arange(m), 2 + rows] = yy
    if soft:
        a[np.arange(m), 2 + k + np.arange(m)] = 1.0
    x0 = np.zeros(nvar)
    x0[: len(start)] = start[: min(len(start), 2 + k)]
    cost = np.zeros(nvar)
    if soft:
        cost[2 + k:] = c

    def fun(x):
        return 0.5 * (x[0] ** 2 + x[1] ** 2) + cost @ x

    def jac(x):
        g = cost.copy()
        g[0:2] += x[0:2]
        return g

    constraints = [{"type": "ineq", "fun": lambda x: a @ x - 1.0, "jac": lambda x: a}]
    bounds = [(None, None)] * (2 + k) + ([(0.0, None)] * m if soft else [])
    res = minimize(fun, x0, jac=jac, method="SLSQP", bounds=bounds, constraints=constraints,
                   options={"maxiter": 500, "ftol": 1e-12})
    return res.x[: 2 + k]


def _svm_qp(z: np.ndarray, lab: np.ndarray, soft: bool, c: float, working: int, max_rounds: int,
            start: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """The primal QP of :func:`svm_fit_qp` by SLSQP with chunking; returns (w, b) in z coordinates."""
    k = lab.shape[0]
    if start is not None:
        x = np.asarray(start, dtype=float).copy()
    else:  # a start from the class means
        diff = (z * (lab == 1).mean(axis=0)[:, None]).sum(0) - (z * (lab == -1).mean(axis=0)[:, None]).sum(0)
        w0 = diff / max(float(np.hypot(*diff)), 1e-12)
        lo, hi = band_gaps(z, lab, w0)
        x = np.concatenate([w0, -(lo + hi) / 2])
    sets: list[set[int]] = []
    for kk in range(k):
        margin = lab[kk] * (z @ x[0:2] + x[2 + kk])
        chosen: set[int] = set()
        for cls in (1.0, -1.0):
            idx = np.flatnonzero(lab[kk] == cls)
            chosen.update(idx[np.argsort(margin[idx], kind="stable")[:working]].tolist())
        sets.append(chosen)
    for _ in range(max_rounds):
        members = [np.array(sorted(s), dtype=int) for s in sets]
        x = _qp([z[m] for m in members], [lab[kk, m] for kk, m in enumerate(members)], soft, c, x)
        violate = lab * (z @ x[0:2] + x[2:, None]) < 1.0 - 1e-6  # left-out points need y f ≥ 1
        added = False
        for kk in range(k):
            new = set(np.flatnonzero(violate[kk]).tolist()) - sets[kk]
            if new:
                sets[kk].update(new)
                added = True
        if not added:
            break
    return x[0:2], x[2:].copy()
