"""The model of paper 003 §3 that the adaptive basis algorithm's three phases share: line
sensors, straight passes and detection times, and the small linear algebra they solve it with.

Sensor k's beam is the line a_k·x + b_k·y = 1 (eq. 1); object l moves as
p_l(t) = (x0_l + vx_l·t, y0_l + vy_l·t) (eq. 2); sensor k detects it at the time t_kl with
a_k·p_l(t_kl) = 1 (eq. 3). The estimates minimise the sum of squared equation errors
τ_kl = a_k·(vx_l·t_kl + x0_l) + b_k·(vy_l·t_kl + y0_l) − 1 (eqs. 4–5) over the measurements that
are known (the view Ω of eq. 21). Nothing but detection times is needed.

Units: times in s; in the adaptive frame lengths are "o1-seconds" (o1 travels one unit per s);
real-world lengths are the deployment's units. Times are handled relative to a per-object
reference time (the mean of that object's detection times) so that large clock values (epoch
seconds) lose no precision; this is a linear reparametrisation of (vx, x0, vy, y0), under which
Newton steps are unchanged. The data's clock may even differ per object (the paper's simulation
times each object from its own entry).

Everything here is pure numpy: deterministic, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from bintrack.errors import BintrackError

OBJECT_UNKNOWNS = 4
LINE_UNKNOWNS = 2
RANK_RTOL = 1e-7  # relative singular value below which a (column-normalised) system is singular
COND_MAX = 1e12  # a block whose (scaled) Newton matrix is worse conditioned is not updated


class DegenerateError(BintrackError, ValueError):
    """Input the algorithm cannot solve (paper 003 §3: e.g. the first two objects parallel, all
    beams parallel, sensor positions collinear); the text says which, in one line."""


def line_through(p: Sequence[float], q: Sequence[float]) -> np.ndarray:
    """(a, b) of the line a·x + b·y = 1 through points ``p`` and ``q`` (eq. 9); DegenerateError
    if the line passes through the origin (it has no such form) or p = q."""
    m = np.array([p, q], dtype=float)
    det = m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]
    scale = max(float(np.abs(m).max()), 1e-300) ** 2
    if abs(det) <= 1e-12 * scale:
        raise DegenerateError("a beam passes through the origin of the adaptive frame")
    return np.linalg.solve(m, np.ones(2))


def null_vector(m: np.ndarray, what: str) -> np.ndarray:
    """The (column-scaled) right singular vector of ``m`` for its smallest singular value;
    DegenerateError if the null space is more than one-dimensional."""
    scale = np.linalg.norm(m, axis=0)
    if np.any(scale == 0):
        raise DegenerateError(f"{what}: a column of the system is zero")
    _, s, vt = np.linalg.svd(m / scale)
    if m.shape[0] >= m.shape[1] - 1 and s[m.shape[1] - 2] <= RANK_RTOL * s[0]:
        raise DegenerateError(f"{what}: the solution is not unique")
    return vt[-1] / scale


def lstsq_rank(m: np.ndarray, rhs: np.ndarray, what: str) -> np.ndarray:
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
    vx, cx, vy, cy = lstsq_rank(m, np.ones(len(tau)), "object: its detections do not fix its path")
    return np.array([cx, cy]), np.array([vx, vy])


def well_conditioned(H: np.ndarray) -> np.ndarray:
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
