"""Lower bounds on how precisely a pass's entry and exit points can be known from its detection
times (paper 003 §3 model, eqs. 1–3), with the beams known or estimated jointly from the passes.

Model, real-world frame: beam k is n_k·p = 1 with n_k = (a_k, b_k) (eq. 1); pass l is
p_l(t) = c_l + v_l·(t − r_l) with w_l = (vx, cx, vy, cy) (eq. 2, c_l its position at its reference
time r_l); sensor k detects it at t_kl = r_l + (1 − n_k·c_l)/(n_k·v_l) (eq. 3) plus timing noise.
The derivatives of t_kl are, with s_kl = n_k·v_l (units/s along the beam's normal):

    ∂t/∂c = −n/s,   ∂t/∂v = −n·(t − r)/s,   ∂t/∂n = −p(t)/s.

**The timing noise.** Detection times are off by e ~ U[−J, J] s. A uniform density has no finite
Fisher information in the regular sense (it is discontinuous at ±J), so the regular Cramér–Rao
bound does not exist, and the Hammersley–Chapman–Robbins bound with a shift of the pass is zero
(shifted supports are never nested). We use the bound for the noise's variance σ² = J²/3: the
information I = JᵀJ/σ² (J the Jacobian above), whose inverse is (i) the Cramér–Rao bound for
Gaussian timing noise of the same variance and (ii), by the Gauss–Markov theorem, the smallest
covariance of any unbiased estimator linear in the (linearised) detection times, whatever their
distribution — least squares attains it. Estimators that exploit the uniform's hard edges (the
Pitman/midrange kind) can do better: for one location from n uniform samples the midrange's
variance 2J²/((n+1)(n+2)) is (n = 6) 0.64× the mean's J²/(3n).

**Entry and exit.** They are where the path crosses the region's border, E(w) = p(t_E(w)); their
covariance is G·C·Gᵀ with G = ∂E/∂w (2 × 4, central differences through
:func:`~.line_model.border_times`) and C the pass's 4 × 4 bound. The figures are the root of its
trace (units), the root-mean-square error an efficient estimator would have.

* :func:`known_beams_bound` — (a): the beams known exactly: C = I_l⁻¹ with
  I_l = Σ_k g_kl g_klᵀ/σ², g_kl = ∂t_kl/∂w_l.
* :func:`unknown_beams_bounds` — (b): the beams unknown, estimated jointly with every pass
  given (the calibration passes known exactly, as phase 3 takes them): C_l is the pass's block of
  the inverse of the joint information, by the Schur complement on the beams
  S = I_bb − Σ_l I_bl I_ll⁻¹ I_lb:  C_l = I_ll⁻¹ + I_ll⁻¹ I_lb S⁻¹ I_bl I_ll⁻¹.

Pure numpy, deterministic, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from bintrack.trackers.laser.line_model import border_times

Box = tuple[float, float, float, float]


def timing_variance(jitter: float) -> float:
    """σ² (s²) of detection-time noise uniform in [−``jitter``, ``jitter``] s: J²/3."""
    return jitter * jitter / 3.0


def time_gradients(lines: np.ndarray, w: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """∂t_k/∂w (k × 4, w = (vx, cx, vy, cy)) and ∂t_k/∂(a_k, b_k) (k × 2) of one pass's noiseless
    detection times by beams ``lines`` (k × 2, units⁻¹), from eq. 3 (module docstring)."""
    vx, cx, vy, cy = (float(x) for x in w)
    n = np.asarray(lines, dtype=float)
    s = n @ np.array([vx, vy])
    tau = (1.0 - n @ np.array([cx, cy])) / s
    gw = -np.column_stack([n[:, 0] * tau, n[:, 0], n[:, 1] * tau, n[:, 1]]) / s[:, None]
    p = np.column_stack([cx + vx * tau, cy + vy * tau])
    return gw, -p / s[:, None]


def crossing_jacobian(w: Sequence[float], t_ref: float, box: Box) -> tuple[np.ndarray, np.ndarray] | None:
    """∂E/∂w and ∂X/∂w (2 × 4 each) of the entry point E and exit point X where the pass crosses
    ``box`` = (xmin, ymin, xmax, ymax); central differences. None if the path misses the box."""
    w = np.asarray(w, dtype=float)

    def ends(x: np.ndarray) -> np.ndarray | None:
        span = border_times(x[[1, 3]], x[[0, 2]], t_ref, box)
        if span is None:
            return None
        return np.concatenate([x[[1, 3]] + x[[0, 2]] * (t - t_ref) for t in span])

    if ends(w) is None:
        return None
    scale = max(float(np.hypot(box[2] - box[0], box[3] - box[1])), 1e-12)
    jac = np.zeros((4, 4))
    for i in range(4):
        h = 1e-7 * max(abs(w[i]), scale if i in (1, 3) else float(np.hypot(w[0], w[2])))
        step = np.zeros(4)
        step[i] = h
        hi, lo = ends(w + step), ends(w - step)
        if hi is None or lo is None:
            return None
        jac[:, i] = (hi - lo) / (2 * h)
    return jac[:2], jac[2:]


def _point_sds(cov: np.ndarray, w: Sequence[float], t_ref: float, box: Box) -> tuple[float, float]:
    jac = crossing_jacobian(w, t_ref, box)
    if jac is None or not np.all(np.isfinite(cov)):
        return math.nan, math.nan
    return tuple(math.sqrt(max(float(np.trace(g @ cov @ g.T)), 0.0)) for g in jac)


def pass_information(lines: np.ndarray, w: Sequence[float], jitter: float, seen: np.ndarray | None = None) -> np.ndarray:
    """I_l = Σ_k g_kl g_klᵀ / σ² (4 × 4, w = (vx, cx, vy, cy)) over the beams that saw the pass
    (``seen``, default all)."""
    gw, _ = time_gradients(lines, w)
    if seen is not None:
        gw = gw[np.asarray(seen, dtype=bool)]
    return gw.T @ gw / timing_variance(jitter)


def known_beams_bound(lines: np.ndarray, w: Sequence[float], t_ref: float, box: Box, jitter: float,
                      seen: np.ndarray | None = None) -> tuple[float, float]:
    """Bound (a), beams known: √trace of the entry's and exit's 2 × 2 covariance bound (units)
    for one pass (w = (vx, cx, vy, cy) at ``t_ref``, real-world, units/s and units). NaN if the
    pass's detections cannot fix it (fewer than four beams, or singular)."""
    info = pass_information(lines, w, jitter, seen)
    try:
        cov = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return math.nan, math.nan
    return _point_sds(cov, w, t_ref, box)


def beam_directions(lines: np.ndarray, positions: Mapping[int, Sequence[float]] | None = None,
                    beams: Sequence[int] = ()) -> list[np.ndarray]:
    """Per beam, the 2 × d basis of the directions its (a, b) may move: both (d = 2) if nothing is
    known of it, the one along the line of beams through its known position q (n·q = 1 holds:
    d = 1), none if its beam is known (``beams``; d = 0)."""
    out = []
    for k in range(len(lines)):
        if k in set(beams):
            out.append(np.zeros((2, 0)))
        elif positions and k in positions:
            qx, qy = (float(v) for v in positions[k])
            out.append(np.array([[-qy], [qx]]) / math.hypot(qx, qy))
        else:
            out.append(np.eye(2))
    return out


def joint_covariances(lines: np.ndarray, passes: np.ndarray, seen: np.ndarray, variance: float,
                      known: Sequence[int] = (), directions: Sequence[np.ndarray] | None = None
                      ) -> tuple[dict[int, np.ndarray], dict[int, np.ndarray]]:
    """The inverse of the joint information of beams and passes, per pass l not ``known``: its
    4 × 4 block C_l = I_ll⁻¹ + I_ll⁻¹ I_lb S⁻¹ I_bl I_ll⁻¹ (Schur complement on the beams, S =
    I_bb − Σ I_bl I_ll⁻¹ I_lb), and the beams' share of it, I_ll⁻¹ I_lb S⁻¹ I_bl I_ll⁻¹ — what
    better beams could still change. Beams move only along ``directions`` (default: freely).
    Raises ``numpy.linalg.LinAlgError`` if the information is singular. Cost linear in passes."""
    lines = np.asarray(lines, dtype=float)
    m, n = len(lines), len(passes)
    dirs = list(directions) if directions is not None else [np.eye(2)] * m
    offsets = np.cumsum([0] + [d.shape[1] for d in dirs])
    nb = int(offsets[-1])
    known = set(int(k) for k in known)
    bb = np.zeros((nb, nb))
    hll, hbl = {}, {}
    for l in range(n):
        use = seen[:, l]
        if not use.any():
            continue
        gw, gb = time_gradients(lines, passes[l])
        gw = np.where(use[:, None], gw, 0.0)
        cross = np.zeros((nb, 4))
        for k in np.flatnonzero(use):
            g = gb[k] @ dirs[k]
            bb[offsets[k]:offsets[k + 1], offsets[k]:offsets[k + 1]] += np.outer(g, g) / variance
            cross[offsets[k]:offsets[k + 1]] = np.outer(g, gw[k]) / variance
        if l not in known:
            hll[l], hbl[l] = gw.T @ gw / variance, cross
    inv = {l: np.linalg.inv(h) for l, h in hll.items()}
    schur = bb - sum((hbl[l] @ inv[l] @ hbl[l].T for l in hll), np.zeros_like(bb))
    schur_inv = np.linalg.inv(schur) if nb else schur
    total, beams = {}, {}
    for l in hll:
        left = inv[l] @ hbl[l].T
        beams[l] = left @ schur_inv @ left.T
        total[l] = inv[l] + beams[l]
    return total, beams


def point_sds(cov: np.ndarray, w: Sequence[float], t_ref: float, box: Box) -> tuple[float, float]:
    """√trace of the entry's and exit's 2 × 2 covariance G·cov·Gᵀ (units) for a pass w with
    4 × 4 covariance ``cov``; NaN if the path misses ``box``."""
    return _point_sds(cov, w, t_ref, box)


def unknown_beams_bounds(lines: np.ndarray, passes: np.ndarray, t_refs: Sequence[float], box: Box, jitter: float,
                         known: Sequence[int] = (), seen: np.ndarray | None = None,
                         positions: Mapping[int, Sequence[float]] | None = None) -> np.ndarray:
    """Bound (b), beams unknown: per pass (rows of ``passes``, n × 4, w at ``t_refs``), √trace of
    the entry's and exit's covariance bound (units, n × 2) when the beams ``lines`` (m × 2) are
    estimated jointly with every pass given; passes ``known`` (the calibration passes) are
    exact and only inform the beams (NaN rows for them); a beam through a known position
    (``positions``: sensor index → (x, y)) moves along one direction only. ``seen`` (m × n):
    which sensor saw which pass (default all). Cost linear in the passes."""
    passes = np.asarray(passes, dtype=float).reshape(-1, 4)
    m, n = len(lines), len(passes)
    seen = np.ones((m, n), dtype=bool) if seen is None else np.asarray(seen, dtype=bool)
    out = np.full((n, 2), np.nan)
    try:
        total, _ = joint_covariances(lines, passes, seen, timing_variance(jitter), known,
                                     beam_directions(np.asarray(lines), positions))
    except np.linalg.LinAlgError:
        return out
    for l, cov in total.items():
        out[l] = _point_sds(cov, passes[l], t_refs[l], box)
    return out
