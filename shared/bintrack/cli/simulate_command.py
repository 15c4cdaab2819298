"""``bintrack simulate SCENARIO --out DIR [--seed N] [options]``: write a simulated dataset."""

from __future__ import annotations

import argparse
import math
import os
import time
from pathlib import Path

from bintrack.argtypes import non_negative_float, output_folder
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
    ("lean", float, "DEG", "beams lean DEG ± 5° (laser-testbed; default 55-70°)"),
    ("offset", float, "FT", "light sensors within ± FT of evenly spaced places (laser-testbed; default 0.32)"),
    ("period", float, "S", "sampling period, s (default: event-driven for uniform-800 and sector-300)"),
    ("pd", float, "P", "detection probability per sample (needs --period)"),
    ("pfa", float, "P", "false-alarm probability per sample (needs --period)"),
    ("clock_offset", float, "S", "per-node clock offsets drawn in ±S seconds"),
    ("clock_skew", float, "X", "per-node clock skews drawn in ±X"),
    ("grid", int, "N", "nodes per side of the grid (darpa-grid, default 12)"),
    ("spacing", float, "M", "distance between neighbouring nodes, m (darpa-grid, default 5)"),
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
    mqtt = parser.add_argument_group("playing the dataset as Zigbee2MQTT devices (README, Real sensors on MQTT)")
    mqtt.add_argument("--publish", metavar="mqtt://HOST:PORT",
                      help="after writing it, publish the dataset to this MQTT broker as Zigbee2MQTT occupancy sensors "
                      "would (topic zigbee2mqtt/<id>, QoS 1), then a message on bintrack/end")
    mqtt.add_argument("--sensor-table", metavar="FILE",
                      help="write the sensor table (TOML) of these devices for the MQTT bridge")
    mqtt.add_argument("--epoch", metavar="ISO8601",
                      help="the time of event time 0 in the payloads and the table (default: now, whole seconds)")
    mqtt.add_argument("--play-speed", type=non_negative_float, default=1.0, metavar="X",
                      help="with --publish: X times real time, 0 as fast as the broker takes them (default: %(default)s)")
    mqtt.add_argument("--mqtt-config", metavar="FILE", help="with --publish: the broker's login and TLS ([broker] table)")
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
    if args.sensor_table or args.publish:
        _as_zigbee(args, out)
    return 0


def _as_zigbee(args: argparse.Namespace, out: Path) -> None:
    """Write the sensor table and/or publish the dataset written at ``out`` (its events as
    ``bintrack track`` reads them) as Zigbee2MQTT devices would."""
    from bintrack.formats import open_dataset
    from bintrack.mqtt.broker_options import BrokerConfigError, broker_options
    from bintrack.mqtt.sensor_table import parse_instant, table_text
    from bintrack.mqtt.zigbee_playback import BASE_TOPIC, check_zigbee, iso_time, zigbee_messages

    dataset = open_dataset(out)
    try:
        check_zigbee(dataset.deployment)
        epoch_us = parse_instant(args.epoch) if args.epoch else int(time.time()) * 1_000_000
    except ValueError as exc:
        raise CommandError(str(exc)) from None
    if args.sensor_table:
        try:
            Path(args.sensor_table).write_text(table_text(dataset.deployment, iso_time(epoch_us)))
        except OSError as exc:
            raise CommandError(f"cannot write {args.sensor_table}: {exc.strerror or exc}") from None
        print(f"{args.sensor_table}: sensor table of {len(dataset.deployment.sensors)} Zigbee2MQTT occupancy sensors "
              f"(topics {BASE_TOPIC}/<id>), event time 0 at {iso_time(epoch_us)}")
    if args.publish:
        from bintrack.mqtt.mqtt_client import publish_messages

        try:
            options = broker_options(args.publish, args.mqtt_config)
            sent = publish_messages(options, zigbee_messages(dataset.events(), epoch_us), speed=args.play_speed,
                                    client_id=f"bintrack-simulate-{os.getpid()}")
        except (BrokerConfigError, ConnectionError) as exc:
            raise CommandError(str(exc)) from None
        print(f"{options.url}: published {sent} messages (QoS 1, acknowledged by the broker), the last on bintrack/end")
