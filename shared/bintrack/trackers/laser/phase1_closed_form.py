"""Phase 1 of the adaptive basis algorithm (paper 003 §5.1): the *adaptive coordinate system*
— object o1 moves along the x axis at speed 1 and is at the origin at a reference time, o2 moves
along the y axis at speed 1 from an unknown point (x̃0_o2, ỹ0_o2) — in which the beams of ≥ 6
sensors and the passes o1…o3 follow in closed form (eqs. 9–20); of the two roots of the
quadratic (eq. 20) the one whose beams fit o4's detection times is kept."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bintrack.trackers.laser.line_model import (
    RANK_RTOL,
    DegenerateError,
    fit_object,
    line_through,
    null_vector,
    predicted_times,
)

# Phase 1 needs six sensors and three objects (eq. 8: nm ≥ 4(n − 2) + 2 + 2m), a fourth object to
# choose the root, and on that fourth object more detections than its four unknowns.
PHASE1_SENSORS = 6
PHASE1_OBJECTS = 4
SIGN_DETECTIONS = 5
PHASE1_WINDOW = 12  # phase 1 looks for its four objects among this many consecutive ones
# phase 1's fourth-object check: RMS time residual at most this fraction of its detection span
CONSISTENCY_RTOL = 0.05


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
    v = null_vector(m, "phase 1 (eq. 18)")
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
