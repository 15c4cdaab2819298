"""The trackers' command-line options, shared by ``bintrack track``, ``bintrack up`` and the
services that run trackers: argparse flags to :class:`TrackerOptions` and back."""

from __future__ import annotations

import argparse

from bintrack.argtypes import int_at_least
from bintrack.trackers import PEER_TRACKERS, TrackerOptions
from bintrack.trackers.laser.adaptive_basis import PHASE2_METHODS
from bintrack.trackers.multi.mcmcda_config import MCMCDAConfig


def add_tracker_arguments(parser: argparse.ArgumentParser) -> None:
    """The trackers' options (but ``--speed``), alike for ``bintrack track``, ``up`` and the services."""
    parser.add_argument("--window", type=int_at_least(1), help="line-fit: estimates in the fitted history (default: 10); "
                        "velocity-plane, svm, ppr, motion-rw: periods per estimate (default: all so far; motion-rw: 1)")
    parser.add_argument("--seed", type=int, default=0, help="mcmcda, motion-rw: seed (default: %(default)s)")
    parser.add_argument("--n-mc", type=int_at_least(1), help=f"mcmcda: MH iterations per scan (default: {MCMCDAConfig.n_mc})")
    parser.add_argument("--scans", type=int_at_least(2), help=f"mcmcda: sliding window, scans (default: {MCMCDAConfig.window})")
    parser.add_argument("--estimates", choices=PEER_TRACKERS, metavar="TRACKER",
                        help="mcmcda: also take this peer tracker's estimates as position reports")
    parser.add_argument("--lag", type=int_at_least(1), metavar="SCANS",
                        help="mcmcda: give each scan's tracks this many scans late, from the sampler's later "
                        "association of its reports, gaps filled and positions smoothed (a fixed-lag smoother; "
                        "default: online)")
    parser.add_argument("--phase2", choices=PHASE2_METHODS,
                        help="adaptive-basis: lsq = eq. 5 to its least-squares optimum after every pass (default), "
                        "paper = 5 Newton iterations per pass (paper 003 §7.2)")


def tracker_arguments(options: TrackerOptions) -> tuple[str, ...]:
    """The command-line options that give a service ``options`` (but ``--estimates``, which
    decides the services themselves)."""
    out: list[str] = []
    for flag, value in (("--speed", options.speed), ("--window", options.window), ("--n-mc", options.n_mc),
                        ("--scans", options.scans), ("--lag", options.lag), ("--phase2", options.phase2)):
        if value is not None:
            out += [flag, str(value)]
    if options.seed:
        out += ["--seed", str(options.seed)]
    return tuple(out)


def tracker_options(args: argparse.Namespace) -> TrackerOptions:
    """The ``TrackerOptions`` of parsed command-line options (absent ones keep their defaults)."""
    fields = {name: getattr(args, name) for name in ("speed", "window", "seed", "n_mc", "scans", "estimates", "lag", "phase2")
              if hasattr(args, name)}
    return TrackerOptions(**{k: v for k, v in fields.items() if v is not None})
