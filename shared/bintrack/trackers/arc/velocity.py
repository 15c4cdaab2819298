"""Target velocity from location estimates timed by one node's local clock (paper 001 §3.2.3).

A node hears its neighbours' estimates (each sent at the sender's transition) and times them
on its own clock, so no clock synchronisation is needed: a clock offset cancels in the time
difference, and a skew only scales the speed by 1/(1 + skew). Only accurate estimates are used
— the midpoints of short arcs. The paper takes the displacement between two of them over their
local time difference; we take the least-squares slope of position against local time over
the last ``span`` accurate ones, which is the two-point rule when there are two and uses the
estimates in between when there are more: on paper 001's §5.4 setting (R = 40, speed R/15,
4 seeds) the mean error falls from 0.39 (two points, 6 apart) to 0.12 units/s (median 0.07;
the paper's mean 0.076), the rest being the first estimates of a run, made from few points.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

DEFAULT_MAX_ARC = 0.5  # rad: an estimate within ±R/4 of the target along the circle
DEFAULT_SPAN = 24  # accurate estimates in the fit
MIN_BASELINE = 2.0  # the displacement must be this many times the two ends' position uncertainty


@dataclass(frozen=True)
class LocalClock:
    """A node's clock: local = (1 + skew)·t + offset, t in event time (s)."""

    offset: float = 0.0
    skew: float = 0.0

    def local(self, t: float) -> float:
        return (1.0 + self.skew) * t + self.offset


class VelocityEstimator:
    """Velocity (units/s) from the accurate estimates one node has heard, on its local clock."""

    def __init__(self, max_arc: float = DEFAULT_MAX_ARC, span: int = DEFAULT_SPAN):
        if not max_arc > 0 or span < 2:
            raise ValueError("max_arc must be > 0 and span at least 2")
        self.max_arc = max_arc
        self._accurate: deque[tuple[float, float, float, float]] = deque(maxlen=span)

    def observe(self, local_time: float, x: float, y: float, arc: float | None,
                radius: float | None = None) -> tuple[float, float] | None:
        """Take an estimate at (x, y) (units) received at ``local_time`` (s, local clock) whose
        final arc has central angle ``arc`` (rad; None = unknown, not used) on a circle of
        ``radius`` (units; its position uncertainty is then radius·arc/2). Returns the current
        velocity estimate, or None while there is none (see :meth:`velocity`)."""
        self.hear(local_time, x, y, arc, radius)
        return self.velocity()

    def hear(self, local_time: float, x: float, y: float, arc: float | None, radius: float | None = None) -> None:
        """Keep an estimate as :meth:`observe` does, without computing the velocity (a neighbour
        that only listens need not fit it until it makes an estimate of its own)."""
        if arc is not None and arc <= self.max_arc:
            if not self._accurate or local_time > self._accurate[-1][0]:
                uncertainty = 0.0 if radius is None else radius * arc / 2
                self._accurate.append((local_time, x, y, uncertainty))

    def velocity(self) -> tuple[float, float] | None:
        """The least-squares velocity (units/s), or None with fewer than two accurate estimates
        or while the oldest and newest are closer than MIN_BASELINE times their summed position
        uncertainty (a displacement that small is mostly error)."""
        if len(self._accurate) < 2:
            return None
        t, x, y, u = np.array(self._accurate).T
        if np.hypot(x[-1] - x[0], y[-1] - y[0]) < MIN_BASELINE * (u[0] + u[-1]):
            return None
        t = t - t.mean()
        denominator = float(t @ t)
        return float(t @ (x - x.mean()) / denominator), float(t @ (y - y.mean()) / denominator)

    @property
    def speed(self) -> float | None:
        v = self.velocity()
        return None if v is None else float(np.hypot(*v))
