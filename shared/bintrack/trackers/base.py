"""The push-style interface every tracker implements (DESIGN §2), and shared neighbourhood state."""

from __future__ import annotations

from typing import Protocol, Union

import numpy as np

from bintrack.bus_payloads import (
    LineObjectEstimate,
    LocalEstimate,
    PositionReports,
    TrackSet,
    Transition,
    VelocityEstimate,
)
from bintrack.deployment_model import Deployment, DiskSensor, SectorSensor
from bintrack.errors import TrackerConfigError
from bintrack.sensing import reports_presence


TrackerInput = Union[Transition, LocalEstimate]
"""What a tracker takes: the network's transitions, and a fusing tracker (mcmcda with peer
estimates) also the peer agents' estimates."""

TrackerOutput = Union[LocalEstimate, PositionReports, TrackSet, LineObjectEstimate, VelocityEstimate]
"""What trackers give: a peer tracker ``LocalEstimate``s; at the base station mcmcda
``PositionReports`` and ``TrackSet``s, adaptive-basis ``LineObjectEstimate``s, the motion
trackers ``VelocityEstimate``s."""


class Tracker(Protocol):
    """Driven alike by a file reader and by a Zenoh subscriber, in event time."""

    name: str

    def update(self, message: TrackerInput) -> list[TrackerOutput]:
        """Take one message in event-time order and return the outputs it causes. Every tracker
        takes transitions; only a tracker that fuses peer estimates is given ``LocalEstimate``s."""

    def flush(self, t: float) -> list[TrackerOutput]:
        """No more transitions at or before event time ``t`` (s) will come: return what is pending."""


class DiskNetwork:
    """Positions, ranges and the neighbour graph of a deployment's disk and sector sensors.

    Neighbours are nodes whose sensing disks intersect (paper 001 §2): |c_i − c_j| < R_i + R_j.
    Indices follow the order of the deployment's range sensors.
    """

    def __init__(self, deployment: Deployment, tracker_name: str):
        sensors = [s for s in deployment.sensors if isinstance(s, (DiskSensor, SectorSensor))]
        if not sensors:
            raise TrackerConfigError(f"tracker {tracker_name} needs disk or sector sensors; this deployment has none")
        self.ids = [s.id for s in sensors]
        self.index = {sid: i for i, sid in enumerate(self.ids)}
        self.positions = np.array([(s.x, s.y) for s in sensors], dtype=float)
        self.ranges = np.array([s.range for s in sensors], dtype=float)
        self._sensors = sensors
        from scipy.spatial import cKDTree  # scipy only once a tracker is made (not for the names)

        tree = cKDTree(self.positions)
        pairs = tree.query_pairs(r=2.0 * float(self.ranges.max()), output_type="ndarray")
        gap = np.linalg.norm(self.positions[pairs[:, 0]] - self.positions[pairs[:, 1]], axis=1)
        pairs = pairs[gap < self.ranges[pairs[:, 0]] + self.ranges[pairs[:, 1]]]
        neighbours: list[list[int]] = [[] for _ in sensors]
        for i, j in pairs:
            neighbours[i].append(int(j))
            neighbours[j].append(int(i))
        self.neighbours = [np.array(sorted(n), dtype=int) for n in neighbours]

    def __len__(self) -> int:
        return len(self.ids)

    def is_present(self, i: int, value: int) -> bool:
        """Whether status ``value`` of node ``i`` means the target is in range (disk 1, sector ≥ 0)."""
        return reports_presence(self._sensors[i], value)

    def neighbourhood(self, i: int) -> np.ndarray:
        """Node ``i`` and its neighbours."""
        return np.append(self.neighbours[i], i)


class SimultaneousTransitions:
    """Holds back the transitions of the latest event time until time moves past it.

    Transitions that share an event time are simultaneous (a field's initial state, sensors
    sampled together), so an estimate at time t must see every status at t. A tracker applies
    each transition's status at once but estimates for the held ones only when :meth:`due`
    releases them: when a later transition arrives, or at ``flush``.
    """

    def __init__(self):
        self._t: float | None = None
        self._held: list[Transition] = []

    def due(self, t: float) -> list[Transition]:
        """Release the held transitions if a transition at event time ``t`` (s) comes after theirs."""
        return self._release() if self._held and t > self._t else []

    def flush(self, t: float) -> list[Transition]:
        """Release the held transitions if no more can come at or before ``t`` (s)."""
        return self._release() if self._held and t >= self._t else []

    def _release(self) -> list[Transition]:
        released, self._held = self._held, []
        return released

    def hold(self, transition: Transition) -> None:
        self._t = transition.t
        self._held.append(transition)
