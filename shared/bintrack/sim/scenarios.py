"""Named scenarios: the settings of the papers (DESIGN §8) as ready-made simulations.

``simulate(name, seed, **options)`` returns ``(deployment, events, truth)``;
``build_scenario(name, seed, **options)`` returns the :class:`~bintrack.sim.engine.Scenario`
(sensors and trajectories) without running it. Options are keyword arguments named as the
command-line options (``sensing_range`` is ``--range``); an option a scenario does not take,
or an impossible value, raises :class:`ScenarioError` with a one-line reason.
"""

from __future__ import annotations

import inspect
import math

import numpy as np

from bintrack.errors import BintrackError
from bintrack.deployment_model import Calibration, CalibrationPass, Deployment, LineSensor, Region
from bintrack.sim import deployments, trajectories
from bintrack.sim.clocks import assign_clocks
from bintrack.sim.engine import FAULTS, Progress, Scenario, SimResult, simulate_scenario
from bintrack.sim.trajectories import Trajectory


class ScenarioError(BintrackError, ValueError):
    """An option a scenario does not take, or an impossible value; the text is one line."""


def option_flag(name: str) -> str:
    """The command-line spelling of an option name."""
    return "--range" if name == "sensing_range" else "--" + name.replace("_", "-")


def _streams(seed: int, count: int) -> list[np.random.Generator]:
    """Independent generators for the parts of a scenario (layout, paths, clocks, phases), so
    that changing one option (say the trajectory) leaves the other parts as they were."""
    if seed < 0:
        raise ScenarioError(f"--seed must be a non-negative integer, got {seed}")
    return [np.random.default_rng(s) for s in np.random.SeedSequence([seed, 0]).spawn(count)]


def _check(condition: bool, message: str) -> None:
    if not condition:
        raise ScenarioError(message)


def _choice(name: str, value: str, allowed: tuple[str, ...]) -> None:
    _check(value in allowed, f"{option_flag(name)} must be one of {', '.join(allowed)}; got {value!r}")


def _positive(name: str, value: float | None) -> None:
    _check(value is None or (math.isfinite(value) and value > 0), f"{option_flag(name)} must be positive, got {value}")


def _probability(name: str, value: float | None) -> None:
    _check(value is None or 0.0 <= value <= 1.0, f"{option_flag(name)} must be within 0..1, got {value}")


# --------------------------------------------------------------------------- papers 000 and 001

FIELD_800 = Region(xmin=0, ymin=0, xmax=800, ymax=800)
# Paper 001 §5.2: trajectories stay in the central square of side 800 − R_max, R_max = 150.
CENTRAL_650 = Region(xmin=75, ymin=75, xmax=725, ymax=725)
TRAJECTORIES_800 = ("linear", "circular", "random", "speed-changes")


def _range_fields(sensing_range: float, model: str, law: str | None, period: float | None,
                  pd: float | None, pfa: float | None) -> dict:
    """The optional range-sensor fields of the sensing model chosen by the options."""
    _choice("model", model, ("ideal", "imperfect"))
    _check(law is None or model == "imperfect", "--law applies to --model imperfect only")
    if law is not None:
        _choice("law", law, ("linear", "exponential"))
    _positive("period", period)
    _probability("pd", pd)
    _probability("pfa", pfa)
    _check(period is not None or (pd is None and pfa is None),
           "--pd and --pfa are per-sample probabilities: they need --period")
    fields = {"period": period, "pd": pd, "pfa": pfa}
    if model == "imperfect":
        fields["range_in"] = round(0.9 * sensing_range, 9)
        fields["detection_law"] = law or "linear"
    return fields


def _paper_path(rng: np.random.Generator, kind: str, speed: float, duration: float | None,
                sensing_range: float) -> Trajectory:
    """One target on the trajectories of paper 001 §5.2/§5.4 within the central square."""
    _choice("trajectory", kind, TRAJECTORIES_800)
    _positive("duration", duration)
    side = CENTRAL_650.width
    try:
        if kind == "linear":
            return trajectories.random_linear(rng, CENTRAL_650, speed, duration or side / speed)
        if kind == "circular":
            return trajectories.random_circular(rng, CENTRAL_650, speed, duration)
        if kind == "random":
            return trajectories.random_turns(rng, CENTRAL_650, speed, duration or side / speed,
                                             (1.5 * sensing_range, 4.0 * sensing_range))
    except ValueError as exc:
        raise ScenarioError(f"{exc}; lower --duration or --speed") from None
    _check(duration is None, "--duration does not apply to --trajectory speed-changes (the path sets it)")
    return trajectories.speed_changes(rng, CENTRAL_650, speed)


def _field_scenario(name: str, seed: int, nodes: int, sensing_range: float, sectors: int | None,
                    speed: float | None, trajectory: str, model: str, law: str | None, faults: str,
                    duration: float | None, period: float | None, pd: float | None, pfa: float | None,
                    clock_offset: float, clock_skew: float) -> Scenario:
    _check(nodes >= 1, f"--nodes must be at least 1, got {nodes}")
    _check(math.isfinite(sensing_range) and 0 < sensing_range <= FIELD_800.width / 2,
           f"--range must be within (0, {FIELD_800.width / 2:g}], got {sensing_range}")
    _positive("speed", speed)
    _choice("faults", faults, FAULTS)
    _check(faults == "none" or period is None, "--faults models event-driven reports: it cannot go with --period")
    _check(clock_offset >= 0 and math.isfinite(clock_offset), f"--clock-offset must be ≥ 0, got {clock_offset}")
    _check(0 <= clock_skew < 0.5, f"--clock-skew must be within [0, 0.5), got {clock_skew}")
    fields = _range_fields(sensing_range, model, law, period, pd, pfa)
    layout, paths, clocks, phases = _streams(seed, 4)
    positions = deployments.uniform_positions(layout, nodes, FIELD_800)
    if sectors is None:
        sensors = deployments.disks_at(positions, sensing_range, **fields)
    else:
        _check(sectors >= 1, f"--sectors must be at least 1, got {sectors}")
        offsets = deployments.random_offsets(layout, nodes)
        sensors = deployments.sectors_at(positions, offsets, sensing_range, sectors, **fields)
    sensors = assign_clocks(sensors, clocks, clock_offset, clock_skew)
    # Paper 001 §5.2: the speed scales with R, constant in sensing ranges per second.
    path = _paper_path(paths, trajectory, speed or sensing_range / 15.0, duration, sensing_range)
    sampling = {}
    if period is not None:
        sampling = dict(zip((s.id for s in sensors), np.round(phases.uniform(0, period, len(sensors)), 6).tolist()))
    deployment = Deployment(name=name, units="unit", region=FIELD_800, sensors=sensors)
    return Scenario(name, deployment, tuple(sensors), (path,), (path.t_entry, path.t_exit),
                    phases=sampling, faults=faults, comm_range=2.0 * sensing_range)


def uniform_800(seed: int = 0, *, nodes: int = 800, sensing_range: float = 40.0, speed: float | None = None,
                trajectory: str = "linear", model: str = "ideal", law: str | None = None, faults: str = "none",
                duration: float | None = None, period: float | None = None, pd: float | None = None,
                pfa: float | None = None, clock_offset: float = 0.0, clock_skew: float = 0.0) -> Scenario:
    """Paper 001 §5.2: ``nodes`` omni-directional binary sensors uniform on 800×800 units with range
    R (40..150), one target at R/15 units/s on a linear, circular, random-turn or speed-changing
    path in the central 650×650 square; ideal or imperfect model (R_in = 0.9R, eq. 25 or 26);
    optional faults of §5.6 (communication range 2R); optional per-node clocks."""
    return _field_scenario("uniform-800", seed, nodes, sensing_range, None, speed, trajectory, model, law,
                           faults, duration, period, pd, pfa, clock_offset, clock_skew)


def sector_300(seed: int = 0, *, nodes: int = 300, sensing_range: float = 100.0, sectors: int = 4,
               speed: float | None = None, trajectory: str = "linear", model: str = "ideal", law: str | None = None,
               duration: float | None = None, period: float | None = None, pd: float | None = None,
               pfa: float | None = None, clock_offset: float = 0.0, clock_skew: float = 0.0) -> Scenario:
    """Paper 000 §V.A: ``nodes`` directional sensors of ``sectors`` sectors with random offsets,
    uniform on 800×800 units, range 50..150, one target at R/15 units/s as in ``uniform-800``."""
    return _field_scenario("sector-300", seed, nodes, sensing_range, sectors, speed, trajectory, model, law,
                           "none", duration, period, pd, pfa, clock_offset, clock_skew)


# --------------------------------------------------------------------------- paper 004

GRID_SIZE = 12
GRID_SPACING = 5.0
GRID_JITTER = 0.5
GRID_DEAD = 6
GRID_FIELD = Region(xmin=0, ymin=0, xmax=(GRID_SIZE - 1) * GRID_SPACING, ymax=(GRID_SIZE - 1) * GRID_SPACING)
WALKING_SPEEDS = (1.0, 1.5)


WALKS = ("straight", "curving")


def _crossing_pairs(people: int) -> list[tuple[int, int]]:
    """The persons who may cross mid-field, in order: (1, 2) or (2, 3), then (4, 5), (6, 7), …."""
    if people < 2:
        return []
    return [(1, 2) if people == 2 else (2, 3)] + [(k, k + 1) for k in range(4, people, 2)]


def _people(rng: np.random.Generator, extra: np.random.Generator, people: int, field: Region, entry_gap: float,
            walk: str, crossings: int, pairs: int, stops: int, spacing: float | None = None) -> list[Trajectory]:
    """People entering ``spacing`` s apart (default ``entry_gap``; person k at spacing·k ±
    entry_gap/10 s) and walking across the field at 1–1.5 m/s.

    ``crossings`` pairs cross each other mid-field: with the default one, the last two of the
    first three (persons 1 and 2 when there are two); further crossings are persons (4, 5),
    (6, 7), …. ``walk="curving"`` bends every walk that is not a crossing: its heading is a mean-reverting random
    walk around its straight course (:func:`trajectories.curve_walk`). ``pairs`` side-by-side
    pairs: the last people walk 2–5 m beside the person before them. ``stops`` people (drawn
    at random) stop for 5–15 s somewhere along their walk. Every draw beyond the default
    scenario's comes from ``extra``, so the defaults give the same people as before."""
    spacing = entry_gap if spacing is None else spacing
    entries = [spacing * k + rng.uniform(-1.0, 1.0) * (entry_gap / 10.0) for k in range(1, people + 1)]
    walks: dict[int, Trajectory] = {}
    for a, b in _crossing_pairs(people)[:crossings]:
        walks[a], walks[b] = trajectories.crossing_walks(rng, field, (entries[a - 1], entries[b - 1]),
                                                         (str(a), str(b)), WALKING_SPEEDS)
    for k in range(1, people + 1):
        if k not in walks:
            walks[k] = trajectories.walk_across(rng, field, rng.uniform(*WALKING_SPEEDS), entries[k - 1], str(k))
    if walk == "curving":
        for k in range(1, people + 1):
            if any(k in c for c in _crossing_pairs(people)[:crossings]):
                continue
            walks[k] = trajectories.curve_walk(extra, field, walks[k])
    for j in range(pairs):
        leader, follower = people - 2 * j - 1, people - 2 * j
        walks[follower] = trajectories.beside(extra, walks[leader], str(follower), (2.0, 5.0))
    for k in extra.choice(np.arange(1, people + 1), size=stops, replace=False) if stops else []:
        walks[int(k)] = trajectories.with_stop(extra, walks[int(k)], (5.0, 15.0))
    return [walks[k] for k in range(1, people + 1)]


def darpa_grid(seed: int = 0, *, people: int = 3, sensing_range: float = 8.0, pd: float = 0.7, pfa: float = 0.05,
               period: float = 0.5, duration: float | None = None, grid: int = GRID_SIZE,
               node_jitter: float = GRID_JITTER, dead: int = GRID_DEAD, entry_gap: float = 10.0,
               walk: str = "straight", crossings: int = 1, pairs: int = 0, stops: int = 0,
               spacing: float = GRID_SPACING) -> Scenario:
    """Paper 004 §V (DARPA NEST 2005): 144 PIR nodes in a 12×12 grid at ≈5 m spacing (jitter
    ±0.5 m), 6 of them dead (listed, never report), range 8 m, pd 0.7, pfa 0.05 per sample,
    sampling every 0.5 s at random phases; ``people`` walk across at 1–1.5 m/s entering about
    10 s apart. The field is observed from 0 s for at least 90 s and until 5 s after the last
    person leaves, with false alarms throughout. A ``duration`` longer than that spreads the
    entries evenly over it (about (duration − 90 s)/people apart, the last one leaving before
    the end), so that a long run is tracked all along (with no crossings then).

    Variations (defaults give the scenario above): ``grid`` nodes per side ``spacing`` m apart
    (a denser or sparser grid over the same field: 16 at 3.5 m, 9 at 7 m), ``node_jitter`` (m),
    ``dead`` nodes, ``entry_gap`` (s between entries), ``walk`` straight|curving, ``crossings``
    (pairs of people crossing mid-field), ``pairs`` (side-by-side pairs), ``stops`` (people
    who stop for a while); see :func:`_people`."""
    _check(people >= 1, f"--people must be at least 1, got {people}")
    _check(math.isfinite(sensing_range) and sensing_range > 0, f"--range must be positive, got {sensing_range}")
    _positive("period", period)
    _positive("duration", duration)
    _positive("entry_gap", entry_gap)
    _probability("pd", pd)
    _probability("pfa", pfa)
    _check(2 <= grid <= 200, f"--grid must be within 2..200 nodes per side, got {grid}")
    _check(math.isfinite(spacing) and spacing > 0, f"--spacing must be positive, got {spacing}")
    _check(math.isfinite(node_jitter) and 0 <= node_jitter < spacing / 2,
           f"--node-jitter must be within [0, {spacing / 2:g}) m, got {node_jitter}")
    _check(0 <= dead <= grid * grid, f"--dead must be within 0..{grid * grid}, got {dead}")
    _choice("walk", walk, WALKS)
    possible = _crossing_pairs(people)
    _check(0 <= crossings <= max(1, len(possible)),
           f"--crossings must be within 0..{len(possible)} with {people} people (persons 2–3, 4–5, … cross)")
    crossers = {k for pair in possible[:crossings] for k in pair}
    _check(pairs >= 0 and not crossers & set(range(people - 2 * pairs + 1, people + 1)) and 2 * pairs <= people,
           f"--pairs {pairs}: the last {2 * pairs} people would include crossing ones; lower --pairs or --crossings")
    _check(0 <= stops <= people, f"--stops must be within 0..{people}, got {stops}")
    layout, paths, phases, extra = _streams(seed, 4)
    field = Region(xmin=0, ymin=0, xmax=(grid - 1) * spacing, ymax=(grid - 1) * spacing)
    positions = deployments.grid_positions(layout, grid, grid, spacing, node_jitter)
    sensors = deployments.disks_at(positions, sensing_range, period=period, pd=pd, pfa=pfa)
    dead_ids = deployments.dead_nodes(layout, [s.id for s in sensors], dead)
    # a long --duration spreads the arrivals over it, so that the whole run has people in it
    longest_walk = math.ceil(math.hypot(field.xmax - field.xmin, field.ymax - field.ymin) / WALKING_SPEEDS[0] + 2.0)
    arrivals = entry_gap if duration is None else max(entry_gap, (duration - longest_walk - entry_gap) / people)
    try:
        walkers = _people(paths, extra, people, field, entry_gap, walk, crossings if arrivals == entry_gap else 0,
                          pairs, stops, arrivals)
    except ValueError as exc:
        raise ScenarioError(f"{exc}; lower --entry-gap or --crossings") from None
    last_exit = max(w.t_exit for w in walkers)
    if duration is None:
        duration = max(90.0, math.ceil(last_exit + 5.0))
    _check(duration >= last_exit, f"--duration {duration:g} s ends before the last person leaves at {last_exit:.1f} s")
    sampling = dict(zip((s.id for s in sensors), np.round(phases.uniform(0, period, len(sensors)), 6).tolist()))
    margin = spacing
    region = Region(xmin=field.xmin - margin, ymin=field.ymin - margin,
                    xmax=field.xmax + margin, ymax=field.ymax + margin)
    deployment = Deployment(name="darpa-grid", units="m", region=region, sensors=sensors)
    return Scenario("darpa-grid", deployment, tuple(sensors), tuple(walkers), (0.0, float(duration)),
                    phases=sampling, dead=dead_ids)


# --------------------------------------------------------------------------- paper 003

TRACK = Region(xmin=0, ymin=0, xmax=16, ymax=8)
CAR_SPEED = 1.41
DETECTION_NOISE = 0.01
LEAN_SPREAD = 5.0  # degrees either side of --lean


def laser_testbed(seed: int = 0, *, passes: int = 32, speed: float = CAR_SPEED,
                  jitter: float = DETECTION_NOISE, lean: float | None = None, offset: float | None = None) -> Scenario:
    """Paper 003 §7.1: a 16 × 8 ft track crossed by 6 laser beams (light sensors along y = 0,
    lasers along y = 8, beams at 55–70° to the track, none parallel); a car at ``speed`` ft/s
    (±5 % per pass) makes ``passes`` straight passes from the left edge x = 0 to the right edge
    x = 16, 2–6 s apart. Pass 1 goes (0, 0) → (16, 0) and pass 2 (0, 0) → (16, 8); both are
    the deployment's calibration passes. Detection times carry U[−``jitter``, ``jitter``] s
    noise (default 0.01 s). ``lean`` (degrees): the beams lean ``lean`` ± 5° instead of 55–70°
    (paper 003 §6: ≈ 63°); ``offset`` (ft): light sensors within ± ``offset`` of evenly spaced
    places (default ± 0.32 ft). The published sensors give the light-sensor position only, not the beam."""
    _check(passes >= 2, f"--passes must be at least 2 (passes 1 and 2 calibrate), got {passes}")
    _positive("speed", speed)
    _check(math.isfinite(jitter) and jitter >= 0, f"--jitter must be a non-negative number of seconds, got {jitter}")
    _check(lean is None or LEAN_SPREAD < lean < 90 - LEAN_SPREAD,
           f"--lean must be between {LEAN_SPREAD:g} and {90 - LEAN_SPREAD:g} degrees, got {lean}")
    _check(offset is None or (math.isfinite(offset) and offset >= 0), f"--offset must be ≥ 0 ft, got {offset}")
    layout, paths = _streams(seed, 2)
    angles = (55.0, 70.0) if lean is None else (lean - LEAN_SPREAD, lean + LEAN_SPREAD)
    sensors = deployments.laser_track(layout, TRACK.width, TRACK.height, angles=angles, offset=offset)
    published = [LineSensor(id=s.id, x=s.x, y=s.y) for s in sensors]
    runs = []
    ends = []
    t = 1.0
    for k in range(1, passes + 1):
        if k == 1:
            y_in, y_out = 0.0, 0.0
        elif k == 2:
            y_in, y_out = 0.0, TRACK.ymax
        else:
            y_in, y_out = (float(y) for y in np.round(paths.uniform(TRACK.ymin, TRACK.ymax, 2), 2))
        pass_speed = round(speed * paths.uniform(0.95, 1.05), 4)
        ends.append(((TRACK.xmin, y_in), (TRACK.xmax, y_out)))
        run = trajectories.polyline(str(k), round(t, 3), ends[-1], pass_speed)
        runs.append(run)
        t = run.t_exit + paths.uniform(2.0, 6.0)
    calibration = Calibration(passes=[
        CalibrationPass.model_validate({"pass": k, "t_entry": run.t_entry, "entry": entry,
                                        "t_exit": run.t_exit, "exit": exit_})
        for k, (run, (entry, exit_)) in enumerate(zip(runs[:2], ends), start=1)])
    deployment = Deployment(name="laser-testbed", units="ft", region=TRACK, sensors=published,
                            calibration=calibration)
    return Scenario("laser-testbed", deployment, tuple(sensors), tuple(runs), (0.0, runs[-1].t_exit),
                    time_noise=jitter)


# --------------------------------------------------------------------------- paper 002

FIELD_300 = Region(xmin=0, ymin=0, xmax=300, ymax=300)
CENTRAL_240 = Region(xmin=30, ymin=30, xmax=270, ymax=270)


def motion(seed: int = 0, *, nodes: int = 100, trajectory: str = "constant", speed: float = 2.0,
           duration: float = 100.0, period: float = 1.0) -> Scenario:
    """Paper 002: ``nodes`` closer/farther sensors uniform on 300 × 300 m, all reporting ±1 every
    ``period`` s (synchronously, from t = 0); one target at ``speed`` m/s for ``duration`` s
    within the central 240 m square, at constant velocity or as a random walk of the velocity
    (σ = 5 % of the speed per period)."""
    _check(nodes >= 1, f"--nodes must be at least 1, got {nodes}")
    _choice("trajectory", trajectory, ("constant", "random-walk"))
    _positive("speed", speed)
    _positive("duration", duration)
    _positive("period", period)
    layout, paths = _streams(seed, 2)
    sensors = deployments.motion_at(deployments.uniform_positions(layout, nodes, FIELD_300), period)
    if trajectory == "constant":
        try:
            path = trajectories.random_linear(paths, CENTRAL_240, speed, duration)
        except ValueError as exc:
            raise ScenarioError(f"{exc}; lower --duration or --speed") from None
    else:
        path = trajectories.random_walk(paths, CENTRAL_240, speed, 0.05 * speed, period, duration)
    deployment = Deployment(name="motion", units="m", region=FIELD_300, sensors=sensors)
    return Scenario("motion", deployment, tuple(sensors), (path,), (path.t_entry, path.t_exit))


# --------------------------------------------------------------------------- registry

SCENARIOS = {
    "uniform-800": uniform_800,
    "sector-300": sector_300,
    "darpa-grid": darpa_grid,
    "laser-testbed": laser_testbed,
    "motion": motion,
}


def scenario_options(name: str) -> list[str]:
    """The option names scenario ``name`` takes."""
    return [p for p in inspect.signature(SCENARIOS[name]).parameters if p != "seed"]


def build_scenario(name: str, seed: int = 0, **options) -> Scenario:
    """The scenario ``name`` with ``options`` (None values mean the scenario's default)."""
    if name not in SCENARIOS:
        raise ScenarioError(f"unknown scenario {name!r} (expected one of: {', '.join(SCENARIOS)})")
    given = {k: v for k, v in options.items() if v is not None}
    allowed = scenario_options(name)
    for key in given:
        _check(key in allowed, f"{option_flag(key)} does not apply to scenario {name} "
                               f"(it takes {', '.join(option_flag(k) for k in allowed)})")
    return SCENARIOS[name](seed, **given)


def simulate(name: str, seed: int = 0, progress: Progress | None = None, **options) -> SimResult:
    """Build and run scenario ``name``: ``(deployment, events sorted by (t, sensor), truth)``."""
    return simulate_scenario(build_scenario(name, seed, **options), seed, progress)
