"""The simulation run: a :class:`Scenario` (sensors and trajectories) to events and truth.

Deterministic given the seed: the random streams come from ``numpy.random.SeedSequence(seed)``
and never from a global generator or the clock. Each sensor is simulated by its kind:
event-driven disks and sectors by exact transitions, periodic ones by sampling, line sensors
by beam crossings (plus detection-time noise), motion sensors by sampling every period.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from bintrack.formats import Event, TruthRow
from bintrack.deployment_model import Deployment, DiskSensor, LineSensor, MotionSensor, SectorSensor
from bintrack.sim.faults import packet_faults, wrong_reports
from bintrack.sim.sampling import periodic_events
from bintrack.sim.trajectories import Trajectory
from bintrack.sim.transitions import beam_crossings, exact_transitions

FAULTS = ("none", "collision", "wrong", "both")

Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class Scenario:
    """What to simulate.

    ``deployment`` is what gets published (deployment.json); ``sensors`` are the same sensors as
    simulated, which may know more (a line sensor's true beam). ``window`` (s) is when periodic
    sensors sample; ``phases`` their sampling phase (s, default 0); ``dead`` sensors never
    report; ``time_noise`` is the half-width (s) of uniform noise on line-sensor detection times;
    ``faults`` one of :data:`FAULTS` with ``comm_range`` (units) for collisions (reports at a
    target's first or last instant are exempt from collisions); truth is
    sampled at least every ``truth_step`` s."""

    name: str
    deployment: Deployment
    sensors: tuple[DiskSensor | SectorSensor | MotionSensor | LineSensor, ...]
    trajectories: tuple[Trajectory, ...]
    window: tuple[float, float]
    phases: Mapping[str, float] = field(default_factory=dict)
    dead: frozenset[str] = frozenset()
    time_noise: float = 0.0
    faults: str = "none"
    comm_range: float | None = None
    truth_step: float | None = 1.0


class SimResult(NamedTuple):
    """A simulated dataset: the deployment, events sorted by (t, sensor), and truth rows."""

    deployment: Deployment
    events: list[Event]
    truth: list[TruthRow]


def truth_rows(trajectories: Sequence[Trajectory], step: float | None = 1.0, tolerance: float = 1e-3) -> list[TruthRow]:
    """truth.csv rows of every target, sorted by time then target order: each path's vertices,
    its exact first and last point, arcs sampled finely enough that linear interpolation is exact
    to ``tolerance`` units, and a row at least every ``step`` s."""
    rows = []
    for order, trajectory in enumerate(trajectories):
        times = trajectory.truth_times(tolerance, step)
        for t, (x, y) in zip(times, trajectory.position(times)):
            rows.append((float(t), order, TruthRow(float(t), trajectory.target, float(x), float(y))))
    rows.sort(key=lambda r: (r[0], r[1]))
    return [r[2] for r in rows]


def sensor_events(sensor, scenario: Scenario, rng: np.random.Generator) -> list[Event]:
    """The true reports of one sensor (before communication faults)."""
    if sensor.id in scenario.dead:
        return []
    trajectories = scenario.trajectories
    if isinstance(sensor, LineSensor):
        events = beam_crossings(sensor, trajectories)
        if scenario.time_noise:
            noise = rng.uniform(-scenario.time_noise, scenario.time_noise, len(events))
            events = [e._replace(t=e.t + float(n)) for e, n in zip(events, noise)]
        return events
    if isinstance(sensor, MotionSensor) or sensor.period is not None:
        return periodic_events(sensor, trajectories, scenario.window, scenario.phases.get(sensor.id, 0.0), rng)
    return exact_transitions(sensor, trajectories, rng)


def simulate_scenario(scenario: Scenario, seed: int = 0, progress: Progress | None = None) -> SimResult:
    """Simulate ``scenario``: every sensor's reports, then the faults, then truth.

    ``seed`` drives the sensing and fault draws (streams independent of those that built the
    scenario); ``progress(done, total)`` is called after each sensor."""
    sense_seed, fault_seed = np.random.SeedSequence([seed, 1]).spawn(2)
    sense_rng = np.random.default_rng(sense_seed)
    events: list[Event] = []
    total = len(scenario.sensors)
    for done, sensor in enumerate(scenario.sensors, start=1):
        events.extend(sensor_events(sensor, scenario, sense_rng))
        if progress is not None:
            progress(done, total)
    events.sort(key=lambda e: (e.t, e.sensor))
    if scenario.faults not in FAULTS:
        raise ValueError(f"unknown fault model {scenario.faults!r}")
    fault_rng = np.random.default_rng(fault_seed)
    if scenario.faults in ("wrong", "both"):
        events = wrong_reports(events, fault_rng)
    if scenario.faults in ("collision", "both"):
        if scenario.comm_range is None:
            raise ValueError("packet collisions need a communication range")
        # Reports at a target's first or last instant give the field's initial or final state,
        # not boundary crossings (paper 001 §5.6 models collisions of crossing reports).
        edges = {t for tr in scenario.trajectories for t in (tr.t_entry, tr.t_exit)}
        positions = {s.id: (s.x, s.y) for s in scenario.sensors}
        kept = packet_faults([e for e in events if e.t not in edges], positions, scenario.comm_range)
        events = sorted(kept + [e for e in events if e.t in edges], key=lambda e: (e.t, e.sensor))
    return SimResult(scenario.deployment, events, truth_rows(scenario.trajectories, scenario.truth_step))
