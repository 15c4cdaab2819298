"""The pure simulator: sensor layouts, target trajectories, exact transitions, periodic sampling,
faults and the named scenarios of the papers. Deterministic given a seed; no I/O (the
``bintrack simulate`` command in :mod:`bintrack.cli.simulate_command` writes the files)."""

from bintrack.sim.engine import Scenario, SimResult, simulate_scenario, truth_rows
from bintrack.sim.scenarios import SCENARIOS, ScenarioError, build_scenario, scenario_options, simulate
from bintrack.sim.trajectories import ArcSegment, LinearSegment, Trajectory

__all__ = [
    "SCENARIOS",
    "ArcSegment",
    "LinearSegment",
    "Scenario",
    "ScenarioError",
    "SimResult",
    "Trajectory",
    "build_scenario",
    "scenario_options",
    "simulate",
    "simulate_scenario",
    "truth_rows",
]
