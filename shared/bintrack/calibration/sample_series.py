"""A dataset's events as a sample matrix: every disk sensor's status at every sampling instant."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from bintrack.formats import Event
from bintrack.deployment_model import Deployment, DiskSensor
from bintrack.sensing import reports_presence


@dataclass(frozen=True)
class SampleSeries:
    """``status[k, i]`` (0/1): sensor ``ids[i]``'s status at event time ``t0 + k·period`` s;
    ``positions`` (n, 2) in deployment units."""

    ids: tuple[str, ...]
    positions: np.ndarray
    period: float
    t0: float
    status: np.ndarray

    @property
    def times(self) -> np.ndarray:
        return self.t0 + self.period * np.arange(len(self.status))


def sample_series(deployment: Deployment, events: Iterable[Event], period: float | None = None) -> SampleSeries:
    """The disk sensors' status sampled every ``period`` s (default: the sensors' longest sampling
    period) from 0 (or the first event, if earlier) to the last event; each sensor starts absent.
    ValueError when there are no disk sensors, no period or no events."""
    sensors = [s for s in deployment.sensors if isinstance(s, DiskSensor)]
    if not sensors:
        raise ValueError("calibration needs disk sensors; this deployment has none")
    if period is None:
        periods = [s.period for s in sensors if s.period]
        if not periods:
            raise ValueError("the sensors give no sampling period (deployment.json: period)")
        period = max(periods)
    index = {s.id: i for i, s in enumerate(sensors)}
    rows = [(e.t, index[e.sensor], reports_presence(sensors[index[e.sensor]], e.value))
            for e in events if e.sensor in index]
    if not rows:
        raise ValueError("no events of the disk sensors")
    t0 = min(0.0, rows[0][0])
    n = int(np.floor(round((rows[-1][0] - t0) / period, 9))) + 1
    status = np.zeros((n, len(sensors)), dtype=np.int8)
    current = np.zeros(len(sensors), dtype=np.int8)
    k = 0
    for t, i, on in rows:
        step = int(np.floor(round((t - t0) / period, 9)))
        while k < step:
            status[k] = current
            k += 1
        current[i] = 1 if on else 0
    status[k:] = current
    return SampleSeries(tuple(s.id for s in sensors), np.array([(s.x, s.y) for s in sensors]), period, t0, status)
