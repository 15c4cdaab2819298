"""Per-node clocks: offset and skew written into the sensors' ``clock_offset``/``clock_skew``.

A node's local time is (1 + skew)·t + offset (DESIGN §5); paper 001's trackers need no
synchronisation, so a peer agent times what it hears with its own clock.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from bintrack.deployment_model import DiskSensor, SectorSensor


def assign_clocks(sensors: Sequence[DiskSensor | SectorSensor], rng: np.random.Generator,
                  max_offset: float, max_skew: float) -> list[DiskSensor | SectorSensor]:
    """Copies of ``sensors`` with offset U[−max_offset, max_offset] (s, rounded to µs) and skew
    U[−max_skew, max_skew] (rounded to 1e-9); with both zero the sensors are returned as they are."""
    if max_skew >= 0.5:
        raise ValueError("clock skew must be below 0.5")
    if max_offset == 0.0 and max_skew == 0.0:
        return list(sensors)
    offsets = np.round(rng.uniform(-max_offset, max_offset, len(sensors)), 6)
    skews = np.round(rng.uniform(-max_skew, max_skew, len(sensors)), 9)
    return [s.model_copy(update={"clock_offset": float(o), "clock_skew": float(k)})
            for s, o, k in zip(sensors, offsets, skews)]
