"""The simulation setup of paper 003 §6 (Fig. 5): line sensors across a passage and straight
passes through it, with their detection times."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from bintrack.sim.deployments import laser_track


class PassPositions(Protocol):
    """What places a pass at a time: the adaptive basis estimator, for one."""

    def position(self, obj: int, t) -> np.ndarray: ...


@dataclass(frozen=True)
class PassageScene:
    """Paper 003 §6 (Fig. 5): line sensors across a passage [0, L] × [0, W] and straight passes
    entering at x = 0 and leaving at x = L. ``lines`` (m × 2) the true beams (a, b), units⁻¹;
    ``objects`` (n × 4) the true (vx, x0, vy, y0) — units/s and units, each object timed from its
    own entry (t = 0 at x = 0, so (x0, y0) is the entry point); ``times`` (m × n) detection times
    (s, eq. 3 plus noise); ``entries``/``exits`` (n × 2) the border points; ``durations`` (n,) s."""

    lines: np.ndarray
    objects: np.ndarray
    times: np.ndarray
    entries: np.ndarray
    exits: np.ndarray
    durations: np.ndarray

    def calibration_pairs(self, basis: PassPositions, objects: Sequence[int] = (0, 1)):
        """(adaptive point, real point) pairs of the entries and exits of ``objects`` — the passes
        known in real-world coordinates (the paper fixes the first two) — for phase 3's
        ``frame_from_points``."""
        pairs = []
        for obj in objects:
            pairs.append((basis.position(obj, 0.0), self.entries[obj]))
            pairs.append((basis.position(obj, self.durations[obj]), self.exits[obj]))
        return pairs


def passage_scene(rng: np.random.Generator, *, sensors: int = 6, objects: int = 4, noise: float = 0.01,
                  speeds: tuple[float, float] = (0.01, 0.1), length: float = 1.0, width: float = 1.0,
                  angles: tuple[float, float] = (60.0, 66.0)) -> PassageScene:
    """The simulation of paper 003 §6: ``sensors`` beams along the passage (the left half leaning
    right, the rest left, at ≈ 63° — the simulator's laser layout), ``objects`` passes at speeds
    U[speeds] (units/s), detection times with U[−noise, noise] s noise. Pass 1 runs along the
    bottom (0, 0) → (L, 0), pass 2 from (0, 0) to (L, W) (fixed, as in the paper, so that they are
    not parallel); the others enter and leave at uniform heights."""
    beams = laser_track(rng, length, width, sensors, angles)
    lines = np.array([(s.a, s.b) for s in beams])
    entries = np.column_stack([np.zeros(objects), rng.uniform(0.0, width, objects)])
    exits = np.column_stack([np.full(objects, length), rng.uniform(0.0, width, objects)])
    fixed_exits = (0.0, width)  # pass 1 along the bottom, pass 2 to the top corner
    for k in range(min(2, objects)):
        entries[k, 1], exits[k, 1] = 0.0, fixed_exits[k]
    speed = rng.uniform(*speeds, objects)
    delta = exits - entries
    durations = np.hypot(*delta.T) / speed
    velocity = delta / durations[:, None]
    objs = np.column_stack([velocity[:, 0], entries[:, 0], velocity[:, 1], entries[:, 1]])
    times = (1.0 - lines @ entries.T) / (lines @ velocity.T)
    times = times + rng.uniform(-noise, noise, times.shape) if noise else times
    return PassageScene(lines, objs, times, entries, exits, durations)
