"""``bintrack simulate SCENARIO --out DIR [--seed N] [options]``: write a simulated dataset."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from bintrack.argtypes import output_folder
from bintrack.errors import CommandError
from bintrack.formats import write_dataset
from bintrack.regions import grid_areas, grid_shape
from bintrack.cli.progress import Progress
from bintrack.sim.engine import simulate_scenario
from bintrack.sim.scenarios import SCENARIOS, ScenarioError, build_scenario, option_flag, scenario_options

HELP = "write a simulated dataset (deployment.json, events.csv, truth.csv) of a named scenario"

# (option name, type, metavar, help); every option defaults to the scenario's own default.
OPTIONS = (
    ("nodes", int, "N", "number of sensor nodes"),
    ("sensing_range", float, "R", "sensing range R, deployment units"),
    ("sectors", int, "S", "sectors per node (sector-300)"),
    ("speed", float, "V", "target speed, units/s (default R/15 for uniform-800 and sector-300)"),
    ("trajectory", str, "KIND", "linear|circular|random|speed-changes, or constant|random-walk (motion)"),
    ("model", str, "MODEL", "sensing model: ideal|imperfect (R_in = 0.9R)"),
    ("law", str, "LAW", "imperfect detection law: linear (paper 001 eq. 25) | exponential (eq. 26)"),
    ("faults", str, "KIND", "none|collision|wrong|both (paper 001 §5.6; uniform-800)"),
    ("duration", float, "S", "how long the target moves (or the field is observed), s"),
    ("people", int, "N", "people walking through the field (darpa-grid)"),
    ("passes", int, "N", "car passes (laser-testbed)"),
    ("jitter", float, "S", "detection-time noise U[-S, S], s (laser-testbed; default 0.01)"),
    ("period", float, "S", "sampling period, s (default: event-driven for uniform-800 and sector-300)"),
    ("pd", float, "P", "detection probability per sample (needs --period)"),
    ("pfa", float, "P", "false-alarm probability per sample (needs --period)"),
    ("clock_offset", float, "S", "per-node clock offsets drawn in ±S seconds"),
    ("clock_skew", float, "X", "per-node clock skews drawn in ±X"),
    ("grid", int, "N", "nodes per side of the grid (darpa-grid, default 12)"),
    ("node_jitter", float, "M", "node position jitter, ± m in x and y (darpa-grid, default 0.5)"),
    ("dead", int, "N", "dead nodes (darpa-grid, default 6)"),
    ("entry_gap", float, "S", "seconds between people's entries (darpa-grid, default 10)"),
    ("walk", str, "KIND", "straight|curving: curving walks' heading is a mean-reverting random walk (darpa-grid)"),
    ("crossings", int, "N", "pairs of people who cross mid-field (darpa-grid, default 1)"),
    ("pairs", int, "N", "side-by-side pairs: the last people walk 2-5 m beside the one before (darpa-grid)"),
    ("stops", int, "N", "people who stop for 5-15 s on their way (darpa-grid)"),
)

# Above this many sensors the command shows its progress on stderr.
PROGRESS_MIN_SENSORS = 100


def add_arguments(parser: argparse.ArgumentParser) -> None:
    lines = [f"  {name}: {' '.join(option_flag(o) for o in scenario_options(name))}" for name in SCENARIOS]
    parser.epilog = "options each scenario takes:\n" + "\n".join(lines)
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("scenario", metavar="SCENARIO", help="one of: " + ", ".join(SCENARIOS)
                        + "; or recording (with --like DIR): DIR's people walked again through DIR's sensors")
    parser.add_argument("--like", metavar="DIR", help="recording: the dataset (deployment.json, events.csv, truth.csv) "
                        "whose truth paths and sensor models to simulate, e.g. the output of bintrack calibrate")
    parser.add_argument("--out", required=True, metavar="DIR", help="dataset folder to write (created if needed)")
    parser.add_argument("--seed", type=int, default=0, metavar="N", help="random seed (default 0)")
    for name, kind, metavar, text in OPTIONS:
        parser.add_argument(option_flag(name), dest=name, type=kind, metavar=metavar, help=text)
    parser.add_argument("--regions", type=region_grid, metavar="CxR|N",
                        help="name regions in deployment.json: the field cut into C columns × R rows of rectangles "
                        "(N: the most square grid of N), each served by a base station of its own")


def like_scenario(path: str | None, options: dict):
    """The ``recording`` scenario of the dataset at ``path``: its sensors sampled over its
    events' time span while its truth's people walk."""
    from bintrack.formats import open_dataset
    from bintrack.sim.recorded_paths import recording_scenario

    if path is None:
        raise CommandError("the scenario recording needs --like DIR")
    given = [option_flag(k) for k, v in options.items() if v is not None]
    if given:
        raise CommandError(f"{given[0]} does not apply to scenario recording (it takes --like)")
    dataset = open_dataset(path)
    if not dataset.has_truth:
        raise CommandError(f"--like {path}: no truth.csv, no paths to walk")
    times = [e.t for e in dataset.events()]
    truth = dataset.truth()
    start = min([0.0, *times[:1]])
    end = max([*times[-1:], *(r.t for r in truth)])
    return recording_scenario(dataset.deployment, truth, (start, end))


def region_grid(text: str) -> tuple[int, int]:
    """``CxR`` or ``N`` → (columns, rows)."""
    try:
        if "x" in text:
            columns, rows = (int(v) for v in text.split("x"))
        else:
            columns, rows = grid_shape(int(text))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected CxR or N (a positive count), got {text!r}") from None
    if columns < 1 or rows < 1:
        raise argparse.ArgumentTypeError(f"expected at least 1x1 regions, got {text!r}")
    return columns, rows


def run(args: argparse.Namespace) -> int:
    options = {name: getattr(args, name) for name, *_ in OPTIONS}
    for name, value in options.items():
        if isinstance(value, float) and not math.isfinite(value):
            raise CommandError(f"{option_flag(name)} must be a finite number, got {value}")
    if args.scenario == "recording":
        scenario = like_scenario(args.like, options)
    elif args.like is not None:
        raise CommandError(f"--like applies to the scenario recording, not {args.scenario}")
    else:
        try:
            scenario = build_scenario(args.scenario, args.seed, **options)
        except ScenarioError as exc:
            raise CommandError(str(exc)) from None
    out = output_folder(Path(args.out))  # options first: a refused run leaves no folder behind
    total = len(scenario.sensors)
    progress = Progress("simulate: sensors", total, enabled=None if total >= PROGRESS_MIN_SENSORS else False)
    result = simulate_scenario(scenario, args.seed, lambda done, _: progress.update(done, force=done == total))
    progress.close()
    deployment = result.deployment
    if args.regions is not None:
        deployment = deployment.model_copy(update={"regions": grid_areas(deployment.region, *args.regions)})
    try:
        write_dataset(out, deployment, result.events, result.truth)
    except OSError as exc:
        raise CommandError(f"cannot write {out}: {exc.strerror or exc}") from None
    span = scenario.window[1] - scenario.window[0]
    targets = len({row.target for row in result.truth})
    print(f"{out}: {len(result.events)} events from {len(result.deployment.sensors)} sensors over "
          f"{span:.1f} s, {targets} target{'s' if targets != 1 else ''}, {len(result.truth)} truth rows")
    return 0
