"""Phase 3 of the adaptive basis algorithm (paper 003 §5.3, §7.1): the affine map
x_adaptive = A·x_real + d (eq. 27) to real-world coordinates, from known sensor positions
(eqs. 28–30), known beams, or known trajectories (calibration passes, eqs. 32–33), by linear
least squares."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from bintrack.trackers.laser.line_model import DegenerateError, lstsq_rank


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
    u = lstsq_rank(m / norm[:, None], y / norm, f"{what}: they do not fix the frame")
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


CALIBRATION_ANGLE_MIN = 10.0  # degrees between the calibration passes' directions
CALIBRATION_SPREAD_MIN = 0.1  # smaller over larger principal spread of their entry and exit points


def calibration_conditioning(passes: Sequence) -> list[str]:
    """Why calibration ``passes`` (each with ``pass_``, ``entry``, ``exit``, units) fix the frame
    of eqs. 32–33 poorly, one line per reason (empty if they do not): the widest angle between
    two passes is below :data:`CALIBRATION_ANGLE_MIN` degrees (near-parallel passes leave the
    frame's shear to the detection noise), or their entry and exit points lie near one line
    (smaller principal spread below :data:`CALIBRATION_SPREAD_MIN` of the larger). Rules of
    thumb: the figures are not measured optima."""
    if len(passes) < 2:
        return []
    names = ", ".join(str(p.pass_) for p in passes)
    out = []
    directions = [np.subtract(p.exit, p.entry, dtype=float) for p in passes]
    widest = 0.0
    for i, u in enumerate(directions):
        for v in directions[i + 1:]:
            cos = abs(float(u @ v)) / max(float(np.linalg.norm(u) * np.linalg.norm(v)), 1e-300)
            widest = max(widest, float(np.degrees(np.arccos(min(cos, 1.0)))))
    if widest < CALIBRATION_ANGLE_MIN:
        out.append(f"calibration passes {names} are within {widest:.3g}° of parallel (below "
                   f"{CALIBRATION_ANGLE_MIN:g}°): the real-world frame they fix is ill-conditioned; "
                   "add a calibration pass across them")
    points = np.array([q for p in passes for q in (p.entry, p.exit)], dtype=float)
    s = np.linalg.svd(points - points.mean(0), compute_uv=False)
    ratio = float(s[1] / s[0]) if s[0] > 0 else 0.0
    if ratio < CALIBRATION_SPREAD_MIN:
        out.append(f"the entry and exit points of calibration passes {names} lie near one line (spread ratio "
                   f"{ratio:.2g}, below {CALIBRATION_SPREAD_MIN:g}): the real-world frame they fix is ill-conditioned")
    return out


def collinear(points: Sequence[Sequence[float]], rtol: float = 1e-3) -> bool:
    """Whether ``points`` (units) lie on one line (or fewer than three distinct points): the smaller
    principal spread is below ``rtol`` of the larger."""
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(p) < 3:
        return True
    s = np.linalg.svd(p - p.mean(0), compute_uv=False)
    return bool(s[0] == 0 or s[1] <= rtol * s[0])
