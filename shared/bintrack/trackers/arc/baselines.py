"""The four comparison algorithms of paper 001 §5.3.1 (Mechitov et al. 2003; Kim et al. 2005).

At each transition of node n, the node estimates the target from the detecting nodes of its
neighbourhood (n and the nodes whose disks intersect n's):

1. ``equal-weight``: the mean of the detecting nodes' positions.
2. ``distance-weight``: weighted mean, weight 4/√(4R² − v²τ²), τ the time since the node
   detected the target, v the target speed.
3. ``duration-weight``: weighted mean, weight ln(1 + τ).
4. ``line-fit``: the distance-weight estimates of the recent past fitted by a line; the
   current position is placed on that line using the target speed.

v is given (``speed``) or, when not, estimated from the data: for distance weight, the mean
chord of a disk crossed by straight lines in uniformly random position and direction is πR/2,
so v ≈ πR / (2·mean detection duration) over the detections completed so far; line fit
takes the slope of its fitted positions against time.
"""

from __future__ import annotations

from collections import deque
from typing import Literal

import numpy as np

from bintrack.bus_payloads import LocalEstimate, Transition
from bintrack.deployment_model import Deployment
from bintrack.trackers.base import DiskNetwork, SimultaneousTransitions

Weighting = Literal["equal", "distance", "duration"]

# 4/√(4R² − v²τ²) has a pole where vτ reaches 2R (the longest chord); the root is floored
# at this fraction of 2R so a long-lasting detection weighs at most 20× a fresh one.
_DISTANCE_FLOOR = 0.05


class SpeedEstimate:
    """Target speed (units/s) from completed detection durations: v ≈ πR̄ / (2·d̄)."""

    def __init__(self, speed: float | None):
        self.fixed = speed
        self._duration_sum = 0.0
        self._range_sum = 0.0
        self._count = 0

    def add(self, duration: float, sensing_range: float) -> None:
        if duration > 0:
            self._duration_sum += duration
            self._range_sum += sensing_range
            self._count += 1

    @property
    def value(self) -> float | None:
        if self.fixed is not None:
            return self.fixed
        if self._count == 0:
            return None
        return np.pi * (self._range_sum / self._count) / (2.0 * self._duration_sum / self._count)


class WeightedCentroidTracker:
    """Algorithms (1)–(3) of paper 001 §5.3.1: a weighted mean of detecting nodes' positions."""

    def __init__(self, deployment: Deployment, weighting: Weighting = "equal", speed: float | None = None):
        if speed is not None and not speed > 0:
            raise ValueError("speed must be positive")
        self.weighting = weighting
        self.name = f"{weighting}-weight"
        self.net = DiskNetwork(deployment, self.name)
        self.present = np.zeros(len(self.net), dtype=bool)
        self.since = np.full(len(self.net), np.nan)
        self.speed = SpeedEstimate(speed)
        self.pending = SimultaneousTransitions()

    def _observe(self, transition: Transition) -> int | None:
        """Update node status; returns the node index, or None for a sensor this tracker ignores."""
        i = self.net.index.get(transition.sensor)
        if i is None:
            return None
        now_present = self.net.is_present(i, transition.value)
        if now_present and not self.present[i]:
            self.since[i] = transition.t
        elif not now_present and self.present[i]:
            self.speed.add(transition.t - self.since[i], self.net.ranges[i])
            self.since[i] = np.nan
        self.present[i] = now_present
        return i

    def _weights(self, nodes: np.ndarray, t: float) -> np.ndarray:
        tau = t - self.since[nodes]
        if self.weighting == "duration":
            w = np.log1p(tau)
        elif self.weighting == "distance" and self.speed.value is not None:
            chord = 2.0 * self.net.ranges[nodes]
            root = np.sqrt(np.maximum(chord**2 - (self.speed.value * tau) ** 2, (_DISTANCE_FLOOR * chord) ** 2))
            w = 4.0 / root
        else:
            w = np.ones(len(nodes))
        if not w.sum() > 0:  # all detections fresh (ln 1 = 0): no timing information yet
            w = np.ones(len(nodes))
        return w

    def centroid(self, i: int, t: float) -> tuple[float, float] | None:
        """Weighted mean position (units) of the detecting nodes around node ``i`` at time t."""
        nodes = self.net.neighbourhood(i)
        nodes = nodes[self.present[nodes]]
        if len(nodes) == 0:
            return None
        w = self._weights(nodes, t)
        x, y = (w[:, None] * self.net.positions[nodes]).sum(axis=0) / w.sum()
        return float(x), float(y)

    def update(self, transition: Transition) -> list[LocalEstimate]:
        out = self._estimates(self.pending.due(transition.t))
        if self._observe(transition) is not None:
            self.pending.hold(transition)
        return out

    def flush(self, t: float) -> list[LocalEstimate]:
        return self._estimates(self.pending.flush(t))

    def _estimates(self, transitions: list[Transition]) -> list[LocalEstimate]:
        out = []
        for tr in transitions:
            point = self.centroid(self.net.index[tr.sensor], tr.t)
            if point is not None:
                out.append(LocalEstimate(t=tr.t, node=tr.sensor, tracker=self.name, x=point[0], y=point[1]))
        return out


class LineFitTracker:
    """Algorithm (4) of paper 001 §5.3.1: distance-weight estimates refined by a fitted line.

    The last ``window`` initial estimates are fitted by the total-least-squares line; each is
    projected onto it (arc length s_i, oriented along the motion) and the current position is
    s̄ + v·(t − t̄) on the line, with v the given target speed, or else the slope of s_i
    against t_i. The estimate carries the velocity v·u.
    """

    name = "line-fit"

    def __init__(self, deployment: Deployment, speed: float | None = None, window: int = 10):
        if window < 2:
            raise ValueError("window must be at least 2")
        self.initial = WeightedCentroidTracker(deployment, "distance", speed)
        self.history: deque[tuple[float, float, float]] = deque(maxlen=window)

    def update(self, transition: Transition) -> list[LocalEstimate]:
        out = self._estimates(self.initial.pending.due(transition.t))
        if self.initial._observe(transition) is not None:
            self.initial.pending.hold(transition)
        return out

    def flush(self, t: float) -> list[LocalEstimate]:
        return self._estimates(self.initial.pending.flush(t))

    def _estimates(self, transitions: list[Transition]) -> list[LocalEstimate]:
        out = []
        for tr in transitions:
            point = self.initial.centroid(self.initial.net.index[tr.sensor], tr.t)
            if point is None:
                continue
            self.history.append((tr.t, *point))
            x, y, vx, vy = self._refine(tr.t, point)
            out.append(LocalEstimate(t=tr.t, node=tr.sensor, tracker=self.name, x=x, y=y, vx=vx, vy=vy))
        return out

    def _refine(self, t: float, point: tuple[float, float]) -> tuple[float, float, float | None, float | None]:
        h = np.array(self.history)
        times, xy = h[:, 0], h[:, 1:]
        if len(h) < 3 or np.ptp(times) <= 0:
            return point[0], point[1], None, None
        centre = xy.mean(axis=0)
        _, _, vt = np.linalg.svd(xy - centre)
        u = vt[0]
        s = (xy - centre) @ u
        slope = np.polyfit(times - times.mean(), s, 1)[0]
        if slope < 0:
            u, s, slope = -u, -s, -slope
        speed = slope if self.initial.speed.fixed is None else self.initial.speed.fixed
        along = s.mean() + speed * (t - times.mean())
        x, y = centre + along * u
        return float(x), float(y), float(speed * u[0]), float(speed * u[1])
