"""Velocity estimators for closer/farther sensors (paper 002, DESIGN §8.5): pure numpy/scipy.

A motion sensor at s reports +1 (closer) in a period when (s − x)·v > 0 and −1 otherwise, so
at each period the line through the target perpendicular to v separates the +1 sensors (ahead)
from the −1 sensors (behind) (paper 002 §II, lemma "+-lem" and the convex-hull proposition).
With a constant velocity the lines of successive periods are parallel and move by |v|·Δt.

Every estimator here works on a *label matrix* ``labels`` of shape (K, N): the status (+1/−1)
of the N sensors (positions ``positions``, shape (N, 2), deployment units) in K consecutive
periods of length ``period`` (s), oldest first. They return a :class:`VelocityFit` (units/s)
or None when the data cannot define one (say, no sensor changed sign).

* :func:`velocity_plane` — paper 002 §III.A: per-sensor counters of +1 periods form a staircase
  over the sensor's projection on the heading; its tangent plane c ≈ g·s + c₀, fitted robustly
  (``scipy.optimize.least_squares``, soft-L1 loss) to the sensors whose counter is neither 0
  nor K (the saturated ones kept as bounds), gives heading g/|g| and speed 1/(|g|·Δt) (the
  paper's v = 1/(tan θ·Δt)).
* :func:`svm_fit` — paper 002 §III.B: maximum-margin line(s) w·s + b_k = 0 separating the +1
  from the −1 positions, one period (eq. svm2) or several with a shared normal w and one
  offset b_k per period (eqs. svm8/svm9 and their extension to any number of periods); soft
  margin (slacks ξ, weight C) when the data are not separable. Heading w/|w|; speed from the
  distance between successive lines, −(b_{k+1} − b_k)/|w|, over Δt (eq. svm10–11; with more
  than two periods the least-squares slope of the line positions against time). Separability
  is decided by a cheap separating direction or ``scipy.optimize.linprog`` (HiGHS); the hard
  margin QP is solved in its exact one-dimensional form (``brentq``, ``minimize_scalar``), the
  soft margin as a convex function of w alone (offsets and slacks minimised exactly,
  ``minimize`` Nelder–Mead); ``solver="qp"`` solves the primal QP itself by SLSQP with chunking
  (Cortes & Vapnik 1995) and gives the same solutions (tested).
* :func:`ppr_fit` — paper 002 §III.C: projection pursuit regression: the direction u for which
  the counters are best fit (least squares) by a non-decreasing function of s·u
  (``scipy.optimize.isotonic_regression``); the fit depends only on the order of the
  projections, so its minimum is reached on an arc of directions and, as in the paper, we take
  the arc's middle ("the mean value of u"). Speed from the staircase along u: the slope γ of the
  clipped ramp fitted to the counters against s·u (as for the plane), |v| = 1/(γ·Δt).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.optimize import brentq, isotonic_regression, least_squares, linprog, minimize, minimize_scalar

TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class VelocityFit:
    """A velocity estimate: ``vx``, ``vy`` in units/s (heading atan2(vy, vx), rad)."""

    vx: float
    vy: float

    @property
    def speed(self) -> float:
        """|v|, units/s."""
        return math.hypot(self.vx, self.vy)

    @property
    def heading(self) -> float:
        """Direction of v, rad from +x in (−π, π]."""
        return math.atan2(self.vy, self.vx)

    @classmethod
    def from_heading(cls, heading: float, speed: float) -> "VelocityFit":
        return cls(speed * math.cos(heading), speed * math.sin(heading))


def counters(labels: np.ndarray) -> np.ndarray:
    """Paper 002 §III.A: for each sensor, the number of periods (rows of ``labels``) it reported +1."""
    return (np.asarray(labels) == 1).sum(axis=0)


def _normaliser(positions: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre (units) and scale (units) that map sensor positions to O(1) coordinates."""
    centre = positions.mean(axis=0)
    scale = float(np.sqrt(((positions - centre) ** 2).sum(axis=1).mean()))
    return centre, (scale if scale > 0 else 1.0)


def _full_rank(points: np.ndarray) -> bool:
    """Whether ``points`` (M, 2) span the plane (not all on one line)."""
    if len(points) < 3:
        return False
    centred = points - points.mean(axis=0)
    s = np.linalg.svd(centred, compute_uv=False)
    return bool(s[1] > 1e-9 * max(s[0], 1e-300))


# --------------------------------------------------------------------------- velocity plane


def _clipped_fit(design: np.ndarray, count: np.ndarray, k: int, start: np.ndarray, loss: str,
                 f_scale: float) -> np.ndarray:
    """Robust least squares of ``count`` by clip(design·p, 0, k): the staircase's tangent plane
    (or ramp) with the saturated sensors (counter 0 or k) kept as bounds — a sensor ahead of the
    whole window must lie where the plane is at least k, one behind it where the plane is ≤ 0."""

    def residual(p):
        return np.clip(design @ p, 0.0, k) - count

    def jac(p):
        f = design @ p
        return design * ((f > 0.0) & (f < k))[:, None]

    return least_squares(residual, start, jac=jac, loss=loss, f_scale=f_scale).x


def velocity_plane(positions: np.ndarray, labels: np.ndarray, period: float,
                   loss: str = "soft_l1", f_scale: float = 1.0) -> VelocityFit | None:
    """Velocity from the tangent plane of the counters' staircase (paper 002 §III.A).

    With constant velocity, sensor s reports +1 while the target's projection on the heading u
    is below s·u, so its counter over K periods is ⌈(s·u − x₀·u)/(|v|Δt)⌉ clipped to [0, K]:
    a staircase whose tangent plane c = g·s + c₀ has g = u/(|v|·Δt). We fit clip(g·s + c₀, 0, K)
    to every sensor's counter by robust least squares (``least_squares`` with ``loss`` and
    ``f_scale`` in counts; the staircase's rounding is ±0.5 count), started from the ordinary
    least-squares plane of the sensors with 0 < counter < K; the saturated sensors act as
    bounds, which keeps short windows (few sensors changed sign) from tilting the plane. Then
    heading = g/|g| and speed = 1/(|g|·``period``) (units/s). None when fewer than three
    unsaturated sensors, all on one line, or a flat plane."""
    positions = np.asarray(positions, dtype=float)
    labels = np.asarray(labels)
    if labels.ndim != 2 or labels.shape[0] < 2:
        return None
    k = labels.shape[0]
    count = counters(labels).astype(float)
    inner = (count > 0) & (count < k)
    if not _full_rank(positions[inner]):
        return None
    centre, scale = _normaliser(positions)
    design = np.column_stack([(positions - centre) / scale, np.ones(len(positions))])
    start = np.linalg.lstsq(design[inner], count[inner], rcond=None)[0]
    fit = _clipped_fit(design, count, k, start, loss, f_scale)
    gradient = fit[:2] / scale  # counts per unit
    norm = float(np.hypot(*gradient))
    if not math.isfinite(norm) or norm <= 0.0:
        return None
    return VelocityFit.from_heading(math.atan2(gradient[1], gradient[0]), 1.0 / (norm * period))


# --------------------------------------------------------------------------- PPR


def _isotonic_sse(count: np.ndarray, projections: np.ndarray) -> np.ndarray:
    """Residual sum of squares of the best non-decreasing fit of ``count`` against each row of
    ``projections`` (M, N) (ties in the projection broken by sensor order)."""
    order = np.argsort(projections, axis=1, kind="stable")
    sse = np.empty(len(projections))
    for m, idx in enumerate(order):
        y = count[idx]
        sse[m] = float(((y - isotonic_regression(y).x) ** 2).sum())
    return sse


def _unit(theta) -> np.ndarray:
    theta = np.asarray(theta, dtype=float)
    return np.stack([np.cos(theta), np.sin(theta)], axis=-1)


def _middle_of_best_run(angles: np.ndarray, best: np.ndarray, widths: np.ndarray) -> float:
    """Middle angle (rad) of the longest circular run of consecutive ``best`` intervals; interval
    m is centred at ``angles[m]`` with width ``widths[m]`` (angles sorted, covering the circle
    or an arc of it)."""
    m = len(angles)
    if best.all():
        return float(angles[0])
    # rotate so that the sequence starts just after a non-best entry: runs do not wrap
    shift = int(np.flatnonzero(~best)[0]) + 1
    order = np.roll(np.arange(m), -shift)
    runs: list[tuple[float, int, int]] = []
    start = None
    for pos, idx in enumerate(order):
        if best[idx] and start is None:
            start = pos
        if start is not None and (not best[idx] or pos == m - 1):
            end = pos if best[idx] else pos - 1
            members = order[start:end + 1]
            runs.append((float(widths[members].sum()), start, end))
            start = None
    _, start, end = max(runs, key=lambda r: (r[0], -r[1]))
    members = order[start:end + 1]
    # the arc from the first member's lower edge to the last member's upper edge
    lo = angles[members[0]] - widths[members[0]] / 2
    hi = angles[members[-1]] + widths[members[-1]] / 2
    if hi < lo:
        hi += TWO_PI
    return float(((lo + hi) / 2) % TWO_PI)


def ppr_direction(positions: np.ndarray, count: np.ndarray, grid: int = 720) -> float | None:
    """Heading (rad) u maximising the fit of ``count`` by a non-decreasing function of s·u
    (paper 002 §III.C, the PPR direction step).

    The isotonic least-squares fit depends on u only through the order of the projections s·u,
    so the criterion is piecewise constant in the angle and changes only where two sensors of
    different counters swap order. We scan ``grid`` equally spaced angles, then examine every
    order change within one grid step of the best run exactly, and return the middle of the
    best arc (the paper's "mean value of u" among the optimal ones). None when all counters
    are equal (no information)."""
    positions = np.asarray(positions, dtype=float)
    count = np.asarray(count, dtype=float)
    if len(count) < 2 or np.all(count == count[0]):
        return None
    centred = positions - positions.mean(axis=0)
    step = TWO_PI / grid
    theta = np.arange(grid) * step
    sse = _isotonic_sse(count, _unit(theta) @ centred.T)
    tol = 1e-9 * max(1.0, float(sse.min()))
    coarse = _middle_of_best_run(theta, sse <= sse.min() + tol, np.full(grid, step))
    # exact refinement: the order changes at angles φ with (s_i − s_j)·u(φ) = 0
    on = sse <= sse.min() + tol
    half_width = (np.count_nonzero(on) if not on.all() else grid) * step / 2 + 2 * step
    half_width = min(half_width, math.pi)
    i, j = np.triu_indices(len(count), k=1)
    differ = count[i] != count[j]
    d = centred[i[differ]] - centred[j[differ]]
    phi = np.arctan2(d[:, 1], d[:, 0]) + math.pi / 2
    critical = np.concatenate([phi, phi + math.pi])
    rel = (critical - coarse + math.pi) % TWO_PI - math.pi
    rel = np.unique(rel[np.abs(rel) < half_width])
    edges = np.concatenate([[-half_width], rel, [half_width]])
    widths = np.diff(edges)
    keep = widths > 1e-12
    mids = ((edges[:-1] + edges[1:]) / 2)[keep]
    widths = widths[keep]
    fine = _isotonic_sse(count, _unit(coarse + mids) @ centred.T)
    best = fine <= fine.min() + 1e-9 * max(1.0, float(fine.min()))
    if fine.min() > sse.min() + tol:  # cannot happen unless the arc was mis-located; keep the scan
        return coarse
    # within the local window, runs do not wrap: pick the widest run of best intervals
    best_run = (0.0, 0, 0)
    start = None
    for m in range(len(mids) + 1):
        if m < len(mids) and best[m]:
            start = m if start is None else start
        elif start is not None:
            width = float(widths[start:m].sum())
            if width > best_run[0]:
                best_run = (width, start, m - 1)
            start = None
    _, a, b = best_run
    lo = mids[a] - widths[a] / 2
    hi = mids[b] + widths[b] / 2
    return float((coarse + (lo + hi) / 2) % TWO_PI)


def staircase_speed(positions: np.ndarray, labels: np.ndarray, heading: float, period: float,
                    loss: str = "soft_l1", f_scale: float = 1.0) -> float | None:
    """Speed (units/s) from the staircase along a known heading u (paper 002 §III.C, the speed
    step): the counters are fit by the ramp clip(γ·(s·u) + c, 0, K) (robust least squares as in
    :func:`velocity_plane`, saturated sensors as bounds) and γ = 1/(|v|·Δt). None with fewer
    than two distinct unsaturated projections or a ramp that does not rise."""
    labels = np.asarray(labels)
    k = labels.shape[0]
    count = counters(labels).astype(float)
    inner = (count > 0) & (count < k)
    p = np.asarray(positions, dtype=float) @ _unit(heading)
    if inner.sum() < 2 or np.ptp(p[inner]) <= 0:
        return None
    centre, scale = float(p.mean()), float(p.std()) or 1.0
    design = np.column_stack([(p - centre) / scale, np.ones(len(p))])
    start = np.linalg.lstsq(design[inner], count[inner], rcond=None)[0]
    if start[0] <= 0:  # the unsaturated sensors alone do not rise: start from the class split
        start = np.array([k / max(np.ptp(design[:, 0]), 1e-12), k / 2.0])
    slope = _clipped_fit(design, count, k, start, loss, f_scale)[0] / scale
    if not math.isfinite(slope) or slope <= 0:
        return None
    return float(1.0 / (slope * period))


def ppr_fit(positions: np.ndarray, labels: np.ndarray, period: float, grid: int = 720) -> VelocityFit | None:
    """Velocity by projection pursuit regression (paper 002 §III.C): heading from
    :func:`ppr_direction` on the counters of all sensors, speed from :func:`staircase_speed`."""
    labels = np.asarray(labels)
    if labels.ndim != 2 or labels.shape[0] < 2:
        return None
    heading = ppr_direction(positions, counters(labels), grid)
    if heading is None:
        return None
    speed = staircase_speed(positions, labels, heading, period)
    if speed is None:
        return None
    return VelocityFit.from_heading(heading, speed)


# --------------------------------------------------------------------------- SVM


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


def _band_gaps(z: np.ndarray, lab: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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
    if _full_rank(z[inner]):
        design = np.column_stack([z[inner], np.ones(int(inner.sum()))])
        candidates.append(np.linalg.lstsq(design, count[inner], rcond=None)[0][:2])
    for w in candidates:
        norm = float(np.hypot(*w))
        if not math.isfinite(norm) or norm == 0:
            continue
        u = w / norm
        lo, hi = _band_gaps(z, lab, u)
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
        lo, hi = _band_gaps(z, lab, np.array([math.cos(theta), math.sin(theta)]))
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


def svm_fit(positions: np.ndarray, labels: np.ndarray, c: float = 1000.0, working: int = 6,
            max_rounds: int = 30, solver: str = "auto") -> SvmResult | None:
    """Maximum-margin line(s) separating the +1 from the −1 sensors (paper 002 §III.B).

    ``labels`` (K, N): one row per period; periods with a single class bound nothing and are
    left out. All periods share the normal w (eqs. svm8–svm9: the two-period problem with
    c₁ = c₂ reduces to the classical one, extended to K periods); each has its own offset b_k.
    Separability is decided by an LP feasibility problem (``linprog``, HiGHS).

    * Separable (hard margin, eq. svm2): with ``solver="auto"`` the QP is solved in its exact
      one-dimensional form (:func:`_max_margin_direction`: maximise over the direction u the
      smallest per-period empty band), which is fast for many periods; with ``solver="qp"``
      the primal QP itself by SLSQP as below (the same solution; a test holds them together).
    * Not separable: soft margin, min ½|w|² + ``c``·Σξ s.t. y (w·z + b_k) ≥ 1 − ξ, ξ ≥ 0, in
      normalised coordinates z (positions centred and divided by their RMS distance to the
      centre). ``solver="auto"``: :func:`_soft_margin` (exact in b and ξ for each w, then a 2-D
      convex minimisation over w). ``solver="qp"``: ``minimize(method="SLSQP")`` on a working
      set of ``working`` points per class and period nearest the current line, grown by every
      point that violates its margin until none does (at most ``max_rounds`` rounds; chunking,
      Cortes & Vapnik 1995); points left out have zero multipliers, so the solution is that of
      the whole problem (slow for many periods: for tests and checks).

    For the hard margin each b_k is centred in its period's empty band (the shared-normal
    problem leaves it free within it). None when no period has both classes."""
    if solver not in ("auto", "qp"):
        raise ValueError(f"unknown SVM solver {solver!r}")
    positions = np.asarray(positions, dtype=float)
    labels = np.asarray(labels)
    if labels.ndim == 1:
        labels = labels[None, :]
    both = np.flatnonzero((labels == 1).any(axis=1) & (labels == -1).any(axis=1))
    if len(both) == 0:
        return None
    centre, scale = _normaliser(positions)
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
    separable = start is not None
    if separable and solver == "auto":
        theta = _max_margin_direction(z, lab, math.atan2(start[1], start[0]))
        u = np.array([math.cos(theta), math.sin(theta)])
        lo, hi = _band_gaps(z, lab, u)
        rho = float((lo - hi).min()) / 2
        w = u / rho
        b = -((lo + hi) / 2) / rho
    elif not separable and solver == "auto":
        w, b = _soft_margin(z, lab, c)
    else:
        w, b = _svm_qp(z, lab, not separable, c, working, max_rounds, start)
        if separable:
            lo, hi = _band_gaps(z, lab, w)
            b = -(lo + hi) / 2
    # back to deployment units: w·(s − centre)/scale + b = (w/scale)·s + (b − w·centre/scale)
    w_units = w / scale
    b_units = b - float(w_units @ centre)
    return SvmResult(w_units, b_units, both, bool(separable))


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
    lo, hi = _band_gaps(z, lab, u)
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


def _svm_qp(z: np.ndarray, lab: np.ndarray, soft: bool, c: float, working: int, max_rounds: int,
            start: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """The primal QP of :func:`svm_fit` by SLSQP with chunking; returns (w, b) in z coordinates."""
    k = lab.shape[0]
    if start is not None:
        x = np.asarray(start, dtype=float).copy()
    else:  # a start from the class means
        diff = (z * (lab == 1).mean(axis=0)[:, None]).sum(0) - (z * (lab == -1).mean(axis=0)[:, None]).sum(0)
        w0 = diff / max(float(np.hypot(*diff)), 1e-12)
        lo, hi = _band_gaps(z, lab, w0)
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
