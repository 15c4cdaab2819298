"""Trackers, by the names of DESIGN §7; every one has the push interface of :mod:`.base`."""

from __future__ import annotations

from collections.abc import Callable

from ..messages import Deployment
from .base import Tracker
from .arc import ArcTracker
from .baselines import LineFitTracker, WeightedCentroidTracker

# name -> factory(deployment, speed=…, window=…)
_FACTORIES: dict[str, Callable[..., Tracker]] = {
    "equal-weight": lambda d, speed=None, window=10: WeightedCentroidTracker(d, "equal", speed),
    "distance-weight": lambda d, speed=None, window=10: WeightedCentroidTracker(d, "distance", speed),
    "duration-weight": lambda d, speed=None, window=10: WeightedCentroidTracker(d, "duration", speed),
    "line-fit": lambda d, speed=None, window=10: LineFitTracker(d, speed, window),
    "arc": lambda d, speed=None, window=10: ArcTracker(d),
}

TRACKER_NAMES = tuple(_FACTORIES)
BASELINES = ("equal-weight", "distance-weight", "duration-weight", "line-fit")


def make_tracker(name: str, deployment: Deployment, *, speed: float | None = None, window: int = 10) -> Tracker:
    """A fresh tracker ``name`` for ``deployment``; ``speed`` (units/s) where the tracker uses one."""
    try:
        factory = _FACTORIES[name]
    except KeyError:
        raise ValueError(f"unknown tracker {name!r} (available: {', '.join(TRACKER_NAMES)})") from None
    return factory(deployment, speed=speed, window=window)


__all__ = ["Tracker", "TRACKER_NAMES", "BASELINES", "make_tracker"]
