"""Velocity estimators for closer/farther sensors (paper 002, DESIGN §8.5): pure numpy/scipy.

A motion sensor at s reports +1 (closer) in a period when (s − x)·v > 0 and −1 otherwise, so
at each period the line through the target perpendicular to v separates the +1 sensors (ahead)
from the −1 sensors (behind) (paper 002 §II, lemma "+-lem" and the convex-hull proposition).
With a constant velocity the lines of successive periods are parallel and move by |v|·Δt.

Every estimator here works on a *label matrix* ``labels`` of shape (K, N): the status (+1/−1)
of the N sensors (positions ``positions``, shape (N, 2), deployment units) in K consecutive
periods of length ``period`` (s), oldest first. They return a :class:`VelocityFit` (units/s)
or None when the data cannot define one (say, no sensor changed sign).

The three estimators, one module each:

* :mod:`.velocity_plane` — paper 002 §III.A, the tangent plane of the counters' staircase;
* :mod:`.svm_estimator` — paper 002 §III.B, maximum-margin lines;
* :mod:`.ppr_estimator` — paper 002 §III.C, projection pursuit regression.

Here: the velocity they return, the counters, and the small geometry they share.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

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


def normaliser(positions: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre (units) and scale (units) that map sensor positions to O(1) coordinates."""
    centre = positions.mean(axis=0)
    scale = float(np.sqrt(((positions - centre) ** 2).sum(axis=1).mean()))
    return centre, (scale if scale > 0 else 1.0)


def full_rank(points: np.ndarray) -> bool:
    """Whether ``points`` (M, 2) span the plane (not all on one line)."""
    if len(points) < 3:
        return False
    centred = points - points.mean(axis=0)
    s = np.linalg.svd(centred, compute_uv=False)
    return bool(s[1] > 1e-9 * max(s[0], 1e-300))


def unit_vector(theta) -> np.ndarray:
    """Unit vector(s) (cos θ, sin θ) of heading(s) ``theta`` (rad), shape theta.shape + (2,)."""
    theta = np.asarray(theta, dtype=float)
    return np.stack([np.cos(theta), np.sin(theta)], axis=-1)

