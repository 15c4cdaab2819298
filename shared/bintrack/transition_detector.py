"""Raw samples → transitions: the pure core of a sensor agent (papers 000, 001).

A binary sensor reports only when its status changes; each sensor numbers its transitions
with ``seq`` from 1 so that a receiver can see a lost one. A line sensor's report is an
instant (the beam was crossed), so every report of it is a transition.
"""

from __future__ import annotations

from bintrack.formats import Event, idle_value
from bintrack.bus_payloads import Transition
from bintrack.deployment_model import Deployment, LineSensor


class TransitionDetector:
    """Turns a stream of samples (events.csv rows or ``RawSample``s) into ``Transition``s."""

    def __init__(self, deployment: Deployment, sensors: list[str] | None = None):
        by_id = deployment.by_id()
        ids = list(by_id) if sensors is None else sensors
        unknown = [s for s in ids if s not in by_id]
        if unknown:
            raise ValueError(f"unknown sensor ids: {', '.join(unknown)}")
        self._instant = {s for s in ids if isinstance(by_id[s], LineSensor)}
        self._status = {s: idle_value(by_id[s]) for s in ids}
        self._seq = dict.fromkeys(ids, 0)

    def update(self, event: Event) -> Transition | None:
        """The transition ``event`` causes, or None when it repeats the sensor's status."""
        change = self.change(event)
        if change is None:
            return None
        return Transition(t=event.t, sensor=event.sensor, value=event.value, previous=change[0], seq=change[1])

    def change(self, event: Event) -> tuple[int, int] | None:
        """(previous status, seq) of the transition ``event`` causes, or None when it repeats the
        sensor's status: :meth:`update` without building the message."""
        previous = self._status[event.sensor]
        if event.value == previous and event.sensor not in self._instant:
            return None
        self._status[event.sensor] = event.value
        self._seq[event.sensor] += 1
        return previous, self._seq[event.sensor]

    def status(self, sensor: str) -> tuple[int, int]:
        """(current status, seq of the last transition) of ``sensor``."""
        return self._status[sensor], self._seq[sensor]
