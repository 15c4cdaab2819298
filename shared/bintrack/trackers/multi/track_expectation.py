"""Where a live track expects its target in the next scan: what online MCMCDA tells the fusion
(paper 004 §III–IV; :mod:`.target_fit` places a target there if the scan supports it)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Expectation:
    """Where a live track expects its target in the scan being fused."""

    x: float
    """predicted position, deployment units"""
    y: float
    sigma: float
    """standard deviation of the predicted position (larger axis), units"""
    vx: float
    """velocity, units/s"""
    vy: float
    reports: int
    """reports the track has taken so far"""
    unreported: int
    """scans since its last report, counting this one (1: it was reported in the previous scan)"""
    unreported_own: int | None = None
    """scans since its last report of its own (not a shared copy) in MCMCDA's window, counting
    this one; None: none in the window"""
