"""Trackers, by the names of DESIGN §7; every one has the push interface of :mod:`.base`.

Peer trackers run in the peer agents, one estimate per node transition (``LocalEstimate``), and
the base station relays them; base trackers run at the base station on the network's
transitions and publish ``TrackSet``s, ``LineObjectEstimate``s or ``VelocityEstimate``s.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

from bintrack.trackers.multi.mcmcda import MCMCDAConfig
from bintrack.messages import Deployment
from bintrack.trackers.laser.tracker import AdaptiveBasisTracker
from bintrack.trackers.arc.arc_tracker import ArcTracker
from bintrack.trackers.base import Tracker
from bintrack.trackers.arc.baselines import LineFitTracker, WeightedCentroidTracker
from bintrack.trackers.multi.tracker import MCMCDATracker
from bintrack.trackers.motion.tracker import MotionRandomWalkTracker, PprTracker, SvmTracker, VelocityPlaneTracker
from bintrack.trackers.arc.sector_tracker import SectorTracker


@dataclass(frozen=True)
class TrackerOptions:
    """The command-line options trackers take (each uses the ones that concern it)."""

    speed: float | None = None
    """target speed, units/s (distance-weight, line-fit; mcmcda: the fastest target); None = estimated
    (mcmcda: people walking, 3 m/s)"""
    window: int | None = None
    """line-fit: estimates in the fitted history (default 10); velocity-plane, svm, ppr,
    motion-rw: periods in the estimate (default: every period so far; motion-rw 1)"""
    seed: int = 0
    """mcmcda: seed of the sampler"""
    n_mc: int | None = None
    """mcmcda: MH iterations per scan (None = the default)"""
    scans: int | None = None
    """mcmcda: sliding-window length in scans (None = the default)"""
    estimates: str | None = None
    """mcmcda: a peer tracker whose estimates join the fused position reports"""
    phase2: str | None = None
    """adaptive-basis: "lsq" (least-squares optimum after every pass, default) or "paper" (5 Newton iterations)"""


LINE_FIT_WINDOW = 10


def _window(o: TrackerOptions) -> dict:
    return {"window": o.window} if o.window is not None else {}


def _mcmcda(d: Deployment, o: TrackerOptions) -> MCMCDATracker:
    speed = {}
    if o.speed is not None:
        fastest = o.speed * d.metres_per_unit  # MCMCDAConfig is in metres; --speed in the deployment's units
        speed = {"max_speed": fastest, "initial_speed": fastest / 2}
    config = replace(MCMCDAConfig(), seed=o.seed, **speed,
                     **({"n_mc": o.n_mc} if o.n_mc is not None else {}),
                     **({"window": o.scans} if o.scans is not None else {}))
    peer = make_tracker(o.estimates, d, replace(o, estimates=None)) if o.estimates is not None else None
    return MCMCDATracker(d, config=config, peer=peer)


_PEER: dict[str, Callable[[Deployment, TrackerOptions], Tracker]] = {
    "equal-weight": lambda d, o: WeightedCentroidTracker(d, "equal", o.speed),
    "distance-weight": lambda d, o: WeightedCentroidTracker(d, "distance", o.speed),
    "duration-weight": lambda d, o: WeightedCentroidTracker(d, "duration", o.speed),
    "line-fit": lambda d, o: LineFitTracker(d, o.speed, o.window or LINE_FIT_WINDOW),
    "arc": lambda d, o: ArcTracker(d),
    "sector": lambda d, o: SectorTracker(d),
}
_BASE: dict[str, Callable[[Deployment, TrackerOptions], Tracker]] = {
    "mcmcda": _mcmcda,
    "adaptive-basis": lambda d, o: AdaptiveBasisTracker(d, **({"phase2": o.phase2} if o.phase2 else {})),
    "velocity-plane": lambda d, o: VelocityPlaneTracker(d, **_window(o)),
    "svm": lambda d, o: SvmTracker(d, **_window(o)),
    "ppr": lambda d, o: PprTracker(d, **_window(o)),
    "motion-rw": lambda d, o: MotionRandomWalkTracker(d, **_window(o), **({"speed": o.speed} if o.speed else {})),
}

TRACKER_NAMES = (*_PEER, *_BASE)
PEER_TRACKERS = tuple(_PEER)
BASE_TRACKERS = tuple(_BASE)
BASELINES = ("equal-weight", "distance-weight", "duration-weight", "line-fit")
OBJECT_TRACKERS = ("adaptive-basis",)
"""trackers whose results are objects.csv rather than tracks.csv"""


def runs_on_peers(name: str) -> bool:
    """Whether tracker ``name`` runs in the peer agents (else at the base station)."""
    return name in _PEER


def check_options(name: str, options: TrackerOptions) -> None:
    """ValueError (one line) if tracker ``name`` does not exist or cannot take ``options``."""
    if name not in _PEER and name not in _BASE:
        raise ValueError(f"unknown tracker {name!r} (available: {', '.join(TRACKER_NAMES)})")
    if name == "line-fit" and options.window is not None and options.window < 2:
        raise ValueError(f"line-fit fits a line to at least 2 estimates: --window {options.window} is too small")
    if options.phase2 is not None and name != "adaptive-basis":
        raise ValueError(f"--phase2 applies to the adaptive-basis tracker only, not {name}")
    if options.estimates is not None:
        if name != "mcmcda":
            raise ValueError(f"peer estimates feed only the mcmcda tracker, not {name}")
        if not runs_on_peers(options.estimates):
            raise ValueError(f"peer estimates come from a peer tracker ({', '.join(_PEER)}), not {options.estimates!r}")


def make_tracker(name: str, deployment: Deployment, options: TrackerOptions = TrackerOptions()) -> Tracker:
    """A fresh tracker ``name`` for ``deployment``."""
    check_options(name, options)
    return (_PEER.get(name) or _BASE[name])(deployment, options)


__all__ = ["Tracker", "TrackerOptions", "TRACKER_NAMES", "PEER_TRACKERS", "BASE_TRACKERS", "BASELINES",
           "OBJECT_TRACKERS", "runs_on_peers", "check_options", "make_tracker"]
