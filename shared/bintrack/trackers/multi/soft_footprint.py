"""Where in a target's neighbourhood the detections place it, under a soft footprint (real PIR).

A real ceiling PIR sensor does not see a disk: the chance that it fires falls off with the
distance d to the person, roughly as a Gaussian (``benchmarks/real_pir_statistics.py``),

    p_i(d) = 1 − (1 − pfa_i)(1 − pd_i·exp(−d² / 2σ_i²)),

σ_i = ``FusionConfig.soft_spread`` × the sensor's fitted range. It is the soft counterpart of the
detection part of paper 004's eq. (4), which has p_i = pd_i inside the disk and pfa_i outside.
The fusion still finds and counts the targets of a scan with the disks (:mod:`.target_fit`); a
target's position report is then the posterior mean and covariance of its position under this
likelihood (flat prior) over the cells near it, given the other targets where they were placed.
Sensors farther than a target's reach plus ``_SIGMAS`` σ take no part (their factor is the same
at every cell).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

_SIGMAS = 3.0


class SoftFootprint:
    """Gaussian footprints of a deployment's sensors (positions and σ in units, pd, pfa per sample)."""

    def __init__(self, positions: np.ndarray, spread: np.ndarray, pd: np.ndarray, pfa: np.ndarray):
        self.positions = positions
        self.spread = spread
        self.pd = np.clip(pd, 1e-6, 1 - 1e-6)
        self.pfa = np.clip(pfa, 1e-6, 1 - 1e-6)
        self.tree = cKDTree(positions)
        self.max_spread = float(spread.max())

    def miss(self, sensors: np.ndarray, points: np.ndarray) -> np.ndarray:
        """(points × sensors) 1 − pd·exp(−d²/2σ²): the chance each sensor misses a person at each point."""
        d2 = ((points[:, None, :] - self.positions[sensors][None, :, :]) ** 2).sum(axis=2)
        return 1.0 - self.pd[sensors] * np.exp(-0.5 * d2 / self.spread[sensors] ** 2)

    def log_likelihood(self, cells: np.ndarray, detecting: np.ndarray, others: np.ndarray, reach: float) -> np.ndarray:
        """Per cell (n × 2, units): log P(the scan's detections | a target there and the other
        targets at ``others`` (m × 2, units)), nats, up to a constant, over the sensors within
        ``reach`` (units) plus 3σ of the cells' centre; ``detecting`` per sensor, 1 = fired."""
        centre = cells.mean(axis=0)
        sensors = np.asarray(self.tree.query_ball_point(centre, r=reach + _SIGMAS * self.max_spread), dtype=int)
        if sensors.size == 0:
            return np.zeros(len(cells))
        quiet = (1.0 - self.pfa[sensors]) * self.miss(sensors, others).prod(axis=0) if len(others) else 1.0 - self.pfa[sensors]
        silent = np.clip(quiet[None, :] * self.miss(sensors, cells), 1e-12, 1 - 1e-12)
        y = detecting[sensors] > 0
        return np.where(y[None, :], np.log1p(-silent), np.log(silent)).sum(axis=1)

    def gains(self, targets: np.ndarray, detecting: np.ndarray, fixed: np.ndarray | None = None) -> np.ndarray:
        """Per target of ``targets`` (m × 2, units): log P(the scan | all the targets) − log P(the
        scan | all but that one), nats, over the sensors within 3σ of it (farther, it changes
        nothing): the evidence for each target given the others and those at ``fixed`` (k × 2,
        units, whose own evidence is not asked); ``detecting`` per sensor."""
        out = np.zeros(len(targets))
        y_all = detecting > 0
        for k, point in enumerate(targets):
            sensors = np.asarray(self.tree.query_ball_point(point, r=_SIGMAS * self.max_spread), dtype=int)
            if sensors.size == 0:
                continue
            own = self.miss(sensors, targets[k:k + 1])[0]
            others = np.delete(targets, k, axis=0)
            if fixed is not None:
                others = np.concatenate([others, fixed])
            without = (1.0 - self.pfa[sensors]) * self.miss(sensors, others).prod(axis=0)
            silent_without = np.clip(without, 1e-12, 1 - 1e-12)
            silent_with = np.clip(without * own, 1e-12, 1 - 1e-12)
            y = y_all[sensors]
            out[k] = float(np.where(y, np.log1p(-silent_with) - np.log1p(-silent_without),
                                    np.log(silent_with) - np.log(silent_without)).sum())
        return out
