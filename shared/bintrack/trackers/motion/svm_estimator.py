"""Maximum-margin lines, paper 002 §III.B: line(s) w·s + b_k = 0 separating the +1 from the −1
positions, one period (eq. svm2) or several with a shared normal w and one offset b_k per
period (eqs. svm8/svm9 and their extension to any number of periods); soft margin (slacks ξ,
weight C) when the data are not separable. Heading w/|w|; speed from the distance between
successive lines, −(b_{k+1} − b_k)/|w|, over Δt (eq. svm10–11; with more than two periods the
least-squares slope of the line positions against time). Separability is decided by a cheap
separating direction or ``scipy.optimize.linprog`` (HiGHS); the hard margin QP is solved in its
exact one-dimensional form (``brentq``, ``minimize_scalar``), the soft margin as a convex
function of w alone (offsets and slacks minimised exactly, ``minimize`` Nelder–Mead). The tests
hold both to a reference that solves the primal QP itself by SLSQP with chunking (Cortes &
Vapnik 1995), which gives the same solutions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.optimize import brentq, linprog, minimize, minimize_scalar

from bintrack.trackers.motion.closer_farther import VelocityFit, full_rank, normaliser


@dataclass(frozen=True)
class SvmResult:
    """Maximum-margin separation of one or more periods with a shared normal (paper 002 §III.B).

    ``w`` is the normal (1/units) and ``b`` the offsets of the usable periods ``periods``
    (indices into the label matrix's rows): the line of period k is w·s + b_k = 0 with the +1
    sensors on the side w·s + b_k > 0. ``separable`` is False when the soft margin was needed.
    ``positions`` (units) are the lines' signed positions along w/|w|, −b_k/|w|."""

    w: np.ndarray
    b: np.ndarray
    periods: np.ndarray
    separable: bool

    @property
    def heading(self) -> float:
        """Direction of the normal w, rad: the target's heading."""
        return math.atan2(self.w[1], self.w[0])

    @property
    def margin(self) -> float:
        """1/|w|, units: half the width of the empty band around each line."""
        return 1.0 / float(np.hypot(*self.w))

    @property
    def positions(self) -> np.ndarray:
        return -self.b / float(np.hypot(*self.w))


def band_gaps(z: np.ndarray, lab: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per period: (smallest projection on u of the +1 points, largest of the −1 points)."""
    proj = z @ u
    lo = np.where(lab == 1, proj[None, :], np.inf).min(axis=1)
    hi = np.where(lab == -1, proj[None, :], -np.inf).max(axis=1)
    return lo, hi


def _feasible_start(z: np.ndarray, lab: np.ndarray) -> np.ndarray | None:
    """A separating (w, b) found cheaply, or None: the direction of the summed differences of
    the class means, or of the counters' plane (:func:`velocity_plane`'s least-squares step),
    when every period's band along it is non-empty. Saves the separability LP in most cases."""
    candidates = []
    plus, minus = (lab == 1), (lab == -1)
    diff = ((plus @ z) / np.maximum(plus.sum(1), 1)[:, None] - (minus @ z) / np.maximum(minus.sum(1), 1)[:, None]).sum(0)
    candidates.append(diff)
    count = plus.sum(axis=0).astype(float)
    inner = (count > 0) & (count < lab.shape[0])
    if full_rank(z[inner]):
        design = np.column_stack([z[inner], np.ones(int(inner.sum()))])
        candidates.append(np.linalg.lstsq(design, count[inner], rcond=None)[0][:2])
    for w in candidates:
        norm = float(np.hypot(*w))
        if not math.isfinite(norm) or norm == 0:
            continue
        u = w / norm
        lo, hi = band_gaps(z, lab, u)
        rho = float((lo - hi).min()) / 2
        if rho > 0:
            return np.concatenate([u / rho, -((lo + hi) / 2) / rho])
    return None


def _max_margin_direction(z: np.ndarray, lab: np.ndarray, theta0: float) -> float:
    """Angle (rad) of the hard-margin SVM normal shared by all periods.

    With w = u/ρ (|u| = 1) the constraints y (w·z + b_k) ≥ 1 hold for some b_k iff every
    period's empty band along u, G_k(u) = min₊ z·u − max₋ z·u, is at least 2ρ; so minimising
    |w| is maximising G(u) = min_k G_k(u). G is concave and positively homogeneous on the plane,
    hence positive on one arc of directions (the feasible ones, containing ``theta0``, e.g. the
    LP's direction) and unimodal on it: we bracket the arc with ``brentq`` and maximise with
    ``minimize_scalar`` (bounded), both from scipy."""

    def gap(theta: float) -> float:
        lo, hi = band_gaps(z, lab, np.array([math.cos(theta), math.sin(theta)]))
        return float((lo - hi).min())

    ends = []
    for sign in (-1.0, 1.0):
        step = 1e-3
        inside = theta0
        while step < math.pi / 2 and gap(theta0 + sign * step) > 0:
            inside = theta0 + sign * step
            step *= 2
        outside = theta0 + sign * min(step, math.pi / 2)
        if gap(outside) > 0:
            ends.append(outside)
        else:
            ends.append(brentq(gap, inside, outside, xtol=1e-13))
    lo, hi = sorted(ends)
    res = minimize_scalar(lambda th: -gap(th), bounds=(lo, hi), method="bounded",
                          options={"xatol": 1e-12, "maxiter": 500})
    return float(res.x)


@dataclass(frozen=True)
class SvmProblem:
    """The separation problem of :func:`svm_fit` before it is solved: the positions in normalised
    coordinates ``z`` (centred on ``centre`` and divided by ``scale``, units), the labels ``lab``
    (K, N) of the usable ``periods`` (those with both classes), and ``start``, a separating
    (w, b_1…b_K) in z coordinates, or None when the periods are not separable."""

    z: np.ndarray
    lab: np.ndarray
    periods: np.ndarray
    centre: np.ndarray
    scale: float
    start: np.ndarray | None

    @property
    def separable(self) -> bool:
        return self.start is not None

    def result(self, w: np.ndarray, b: np.ndarray) -> SvmResult:
        """The solution (w, b) in z coordinates as an :class:`SvmResult` in deployment units."""
        # w·(s − centre)/scale + b = (w/scale)·s + (b − w·centre/scale)
        w_units = w / self.scale
        b_units = b - float(w_units @ self.centre)
        return SvmResult(w_units, b_units, self.periods, bool(self.separable))


def svm_problem(positions: np.ndarray, labels: np.ndarray) -> SvmProblem | None:
    """The problem of :func:`svm_fit` for ``positions`` (N, 2, units) and ``labels`` (K, N, or
    one period's N); separability by a cheap separating direction (:func:`_feasible_start`) or
    an LP feasibility problem (``linprog``, HiGHS). None when no period has both classes."""
    positions = np.asarray(positions, dtype=float)
    labels = np.asarray(labels)
    if labels.ndim == 1:
        labels = labels[None, :]
    both = np.flatnonzero((labels == 1).any(axis=1) & (labels == -1).any(axis=1))
    if len(both) == 0:
        return None
    centre, scale = normaliser(positions)
    z = (positions - centre) / scale
    lab = labels[both].astype(float)  # (K, N)
    k, n = lab.shape
    start = _feasible_start(z, lab)
    if start is None:
        # separability LP: find w, b with y (w·z + b_k) ≥ 1 for every point
        rows = np.arange(k * n)
        a_ub = sparse.csr_matrix(sparse.hstack([
            sparse.csr_matrix(-(lab[:, :, None] * z[None, :, :]).reshape(-1, 2)),
            sparse.csr_matrix((-lab.reshape(-1), (rows, np.repeat(np.arange(k), n))), shape=(k * n, k))]))
        lp = linprog(np.zeros(2 + k), A_ub=a_ub, b_ub=-np.ones(k * n), bounds=[(None, None)] * (2 + k),
                     method="highs")
        if lp.status == 0:
            start = lp.x
    return SvmProblem(z, lab, both, centre, scale, start)


def svm_fit(positions: np.ndarray, labels: np.ndarray, c: float = 1000.0) -> SvmResult | None:
    """Maximum-margin line(s) separating the +1 from the −1 sensors (paper 002 §III.B).

    ``labels`` (K, N): one row per period; periods with a single class bound nothing and are
    left out. All periods share the normal w (eqs. svm8–svm9: the two-period problem with
    c₁ = c₂ reduces to the classical one, extended to K periods); each has its own offset b_k.
    Separability is decided by an LP feasibility problem (``linprog``, HiGHS; :func:`svm_problem`).

    * Separable (hard margin, eq. svm2): the QP is solved in its exact one-dimensional form
      (:func:`_max_margin_direction`: maximise over the direction u the smallest per-period
      empty band), which is fast for many periods.
    * Not separable: soft margin, min ½|w|² + ``c``·Σξ s.t. y (w·z + b_k) ≥ 1 − ξ, ξ ≥ 0, in
      normalised coordinates z (positions centred and divided by their RMS distance to the
      centre): :func:`_soft_margin` (exact in b and ξ for each w, then a 2-D convex
      minimisation over w).

    For the hard margin each b_k is centred in its period's empty band (the shared-normal
    problem leaves it free within it). None when no period has both classes."""
    problem = svm_problem(positions, labels)
    if problem is None:
        return None
    z, lab = problem.z, problem.lab
    if problem.separable:
        start = problem.start
        theta = _max_margin_direction(z, lab, math.atan2(start[1], start[0]))
        u = np.array([math.cos(theta), math.sin(theta)])
        lo, hi = band_gaps(z, lab, u)
        rho = float((lo - hi).min()) / 2
        w = u / rho
        b = -((lo + hi) / 2) / rho
    else:
        w, b = _soft_margin(z, lab, c)
    return problem.result(w, b)


def _hinge_offsets(z: np.ndarray, lab: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For a normal w: each period's offset b_k minimising Σ_i max(0, 1 − y_i (w·z_i + b_k)) and
    that minimum. The loss of point i is max(0, y_i (β_i − b)) with β_i = y_i − w·z_i, convex
    piecewise linear in b; its minimum is at the breakpoint where the slope
    −#{+1 : β > b} + #{−1 : β ≤ b} first becomes ≥ 0 (a weighted median)."""
    beta = lab - (z @ w)[None, :]
    order = np.argsort(beta, axis=1, kind="stable")
    sb = np.take_along_axis(beta, order, axis=1)
    sy = np.take_along_axis(lab, order, axis=1)
    plus = np.cumsum(sy == 1, axis=1)
    minus = np.cumsum(sy == -1, axis=1)
    slope = -(plus[:, -1:] - plus) + minus
    first = np.argmax(slope >= 0, axis=1)
    b = sb[np.arange(len(sb)), first]
    loss = np.maximum(0.0, lab * (beta - b[:, None])).sum(axis=1)
    return b, loss


def _soft_margin(z: np.ndarray, lab: np.ndarray, c: float) -> tuple[np.ndarray, np.ndarray]:
    """Soft-margin SVM with a shared normal, min_w ½|w|² + c·Σ_k min_{b_k} Σ_i hinge: the slacks
    and offsets are minimised exactly for each w (:func:`_hinge_offsets`), leaving a convex
    function of the two components of w, minimised by ``scipy.optimize.minimize``
    (Nelder–Mead, restarted from its result until it no longer improves)."""
    diff = ((lab == 1) @ z / np.maximum((lab == 1).sum(1), 1)[:, None]
            - (lab == -1) @ z / np.maximum((lab == -1).sum(1), 1)[:, None]).sum(0)
    norm = float(np.hypot(*diff))
    u = diff / norm if norm > 0 else np.array([1.0, 0.0])
    lo, hi = band_gaps(z, lab, u)
    spread = float(np.median(np.abs(lo - hi))) or 1.0
    w = u * (2.0 / spread)

    def objective(x: np.ndarray) -> float:
        return 0.5 * float(x @ x) + c * float(_hinge_offsets(z, lab, x)[1].sum())

    best = objective(w)
    for _ in range(10):
        res = minimize(objective, w, method="Nelder-Mead",
                       options={"xatol": 1e-9 * max(1.0, float(np.hypot(*w))), "fatol": 1e-12 * max(1.0, best),
                                "maxiter": 4000, "initial_simplex": np.array([w, w + [0.1 * np.hypot(*w), 0],
                                                                               w + [0, 0.1 * np.hypot(*w)]])})
        improved = res.fun < best - 1e-12 * max(1.0, abs(best))
        w, best = (res.x, res.fun) if res.fun <= best else (w, best)
        if not improved:
            break
    return w, _hinge_offsets(z, lab, w)[0]


def svm_velocity(positions: np.ndarray, labels: np.ndarray, times: np.ndarray, c: float = 1000.0) -> VelocityFit | None:
    """Velocity from the multi-period SVM (paper 002 eqs. svm8–svm11): heading w/|w|, speed the
    least-squares slope of the lines' positions −b_k/|w| (units) against the periods' times
    ``times`` (s); for two periods exactly (−b₂ + b₁)/(|w|·Δt). None with fewer than two usable
    periods or a line that does not move forward."""
    result = svm_fit(positions, labels, c)
    if result is None or len(result.periods) < 2:
        return None
    t = np.asarray(times, dtype=float)[result.periods]
    slope = float(np.polyfit(t - t.mean(), result.positions, 1)[0])
    if not math.isfinite(slope) or slope <= 0:
        return None
    return VelocityFit.from_heading(result.heading, slope)
