"""Trackers, by the names of DESIGN §7; every one has the push interface of :mod:`.base`.

Peer trackers run in the peer agents, one estimate per node transition (``LocalEstimate``), and
the base station relays them; base trackers run at the base station on the network's
transitions and publish ``TrackSet``s, ``LineObjectEstimate``s or ``VelocityEstimate``s.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

from bintrack.deployment_model import Deployment
from bintrack.errors import TrackerConfigError
from bintrack.trackers.base import Tracker

# Each factory imports its tracker's module when called: a service loads the one tracker it runs
# (the multi-target and motion trackers pull in scipy's optimisers and sparse matrices).


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
    lag: int | None = None
    """mcmcda: give each scan's tracks this many scans late, smoothed with the scans after it
    (:mod:`bintrack.trackers.multi.fixed_lag`); None = online, each scan's tracks at once"""
    phase2: str | None = None
    """adaptive-basis: "lsq" (least-squares optimum after every pass, default) or "paper" (5 Newton iterations)"""


LINE_FIT_WINDOW = 10


def _window(o: TrackerOptions) -> dict:
    return {"window": o.window} if o.window is not None else {}


def _weighted(weights: str) -> Callable[[Deployment, TrackerOptions], Tracker]:
    def make(d: Deployment, o: TrackerOptions) -> Tracker:
        from bintrack.trackers.arc.baselines import WeightedCentroidTracker

        return WeightedCentroidTracker(d, weights, o.speed)

    return make


def _line_fit(d: Deployment, o: TrackerOptions) -> Tracker:
    from bintrack.trackers.arc.baselines import LineFitTracker

    return LineFitTracker(d, o.speed, o.window or LINE_FIT_WINDOW)


def _arc(d: Deployment, o: TrackerOptions) -> Tracker:
    from bintrack.trackers.arc.arc_tracker import ArcTracker

    return ArcTracker(d)


def _sector(d: Deployment, o: TrackerOptions) -> Tracker:
    from bintrack.trackers.arc.sector_tracker import SectorTracker

    return SectorTracker(d)


def _adaptive_basis(d: Deployment, o: TrackerOptions) -> Tracker:
    from bintrack.trackers.laser.tracker import AdaptiveBasisTracker

    return AdaptiveBasisTracker(d, **({"phase2": o.phase2} if o.phase2 else {}))


def _motion(kind: str) -> Callable[[Deployment, TrackerOptions], Tracker]:
    def make(d: Deployment, o: TrackerOptions) -> Tracker:
        from bintrack.trackers.motion import tracker as motion

        if kind == "motion-rw":
            return motion.MotionRandomWalkTracker(d, **_window(o), **({"speed": o.speed} if o.speed else {}))
        return {"velocity-plane": motion.VelocityPlaneTracker, "svm": motion.SvmTracker,
                "ppr": motion.PprTracker}[kind](d, **_window(o))

    return make


def _mcmcda(d: Deployment, o: TrackerOptions) -> Tracker:
    from bintrack.trackers.multi.fusion_config import FusionConfig
    from bintrack.trackers.multi.mcmcda_config import MCMCDAConfig
    from bintrack.trackers.multi.pir_settings import pir_settings
    from bintrack.trackers.multi.tracker import MCMCDATracker

    fusion, base = pir_settings(d, FusionConfig(), MCMCDAConfig())
    speed = {}
    if o.speed is not None:
        fastest = o.speed * d.metres_per_unit  # MCMCDAConfig is in metres; --speed in the deployment's units
        speed = {"max_speed": fastest, "initial_speed": fastest / 2}
    config = replace(base, seed=o.seed, **speed,
                     **({"n_mc": o.n_mc} if o.n_mc is not None else {}),
                     **({"window": o.scans} if o.scans is not None else {}))
    peer = make_tracker(o.estimates, d, replace(o, estimates=None, lag=None)) if o.estimates is not None else None
    tracker = MCMCDATracker(d, fusion=fusion, config=config, peer=peer)
    if o.lag is None:
        return tracker
    from bintrack.trackers.multi.fixed_lag import FixedLagSmoother

    return FixedLagSmoother(tracker, o.lag)


_PEER: dict[str, Callable[[Deployment, TrackerOptions], Tracker]] = {
    "equal-weight": _weighted("equal"),
    "distance-weight": _weighted("distance"),
    "duration-weight": _weighted("duration"),
    "line-fit": _line_fit,
    "arc": _arc,
    "sector": _sector,
}
_BASE: dict[str, Callable[[Deployment, TrackerOptions], Tracker]] = {
    "mcmcda": _mcmcda,
    "adaptive-basis": _adaptive_basis,
    **{name: _motion(name) for name in ("velocity-plane", "svm", "ppr", "motion-rw")},
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


def check_options(name: str, options: TrackerOptions, regional: bool = False) -> None:
    """TrackerConfigError (one line) if tracker ``name`` does not exist or cannot take ``options``
    (``regional``: at a region's base station, whose tracks the merge takes online)."""
    if name not in _PEER and name not in _BASE:
        raise TrackerConfigError(f"unknown tracker {name!r} (available: {', '.join(TRACKER_NAMES)})")
    if name == "line-fit" and options.window is not None and options.window < 2:
        raise TrackerConfigError(f"line-fit fits a line to at least 2 estimates: --window {options.window} is too small")
    if options.lag is not None and name != "mcmcda":
        raise TrackerConfigError(f"--lag smooths the mcmcda tracker's tracks only, not {name}'s")
    if options.lag is not None and regional:
        raise TrackerConfigError("--lag smooths one base station's tracks; the merge of regions takes them online")
    if options.phase2 is not None and name != "adaptive-basis":
        raise TrackerConfigError(f"--phase2 applies to the adaptive-basis tracker only, not {name}")
    if options.estimates is not None:
        if name != "mcmcda":
            raise TrackerConfigError(f"peer estimates feed only the mcmcda tracker, not {name}")
        if not runs_on_peers(options.estimates):
            raise TrackerConfigError(f"peer estimates come from a peer tracker ({', '.join(_PEER)}), not {options.estimates!r}")


# the sensor kinds each tracker is made for (paper by paper)
_MADE_FOR = {**{name: ("disk",) for name in (*BASELINES, "arc")}, "sector": ("sector",), "mcmcda": ("disk", "sector"),
             "adaptive-basis": ("line",), **{name: ("motion",) for name in ("velocity-plane", "svm", "ppr", "motion-rw")}}


def sensor_mismatch(name: str, deployment: Deployment) -> str | None:
    """Why tracker ``name`` does not fit ``deployment``'s sensors (one line), or None if some of
    them are of a kind it is made for."""
    kinds = sorted({sensor.kind for sensor in deployment.sensors})
    wanted = _MADE_FOR.get(name, ())
    if not wanted or set(kinds) & set(wanted):
        return None
    return (f"tracker {name} is made for {' or '.join(wanted)} sensors; this deployment has "
            f"{', '.join(kinds) or 'no'} sensors only")


def make_tracker(name: str, deployment: Deployment, options: TrackerOptions = TrackerOptions()) -> Tracker:
    """A fresh tracker ``name`` for ``deployment``."""
    check_options(name, options)
    return (_PEER.get(name) or _BASE[name])(deployment, options)


__all__ = ["Tracker", "TrackerOptions", "TRACKER_NAMES", "PEER_TRACKERS", "BASE_TRACKERS", "BASELINES",
           "OBJECT_TRACKERS", "runs_on_peers", "check_options", "make_tracker", "sensor_mismatch"]
