"""``bintrack import MATRIX --sensors TABLE --out DIR``: a recording of binary sensors (a sample
matrix and a sensor table, optionally CVML ground truth) as a DESIGN §6 dataset, in metres
(:mod:`bintrack.importers`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pydantic import ValidationError

from bintrack.argtypes import area_type, int_at_least, output_folder, positive_float
from bintrack.errors import CommandError
from bintrack.formats import read_floor_plan, write_dataset
from bintrack.importers.binary_matrix import (METRES_PER, matrix_events, parse_columns, read_sample_matrix,
                                              read_sensor_table)
from bintrack.importers.cvml import read_cvml
from bintrack.deployment_model import Deployment, DiskSensor, Region


def _columns(text: str) -> list[int]:
    try:
        return parse_columns(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _probability(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0 <= value <= 1:
        raise argparse.ArgumentTypeError(f"must be a probability in [0, 1], got {text!r}")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("matrix", metavar="MATRIX", help="binary samples: one row per period, one column per sensor "
                        "(whitespace or commas; non-zero = detecting)")
    parser.add_argument("--sensors", required=True, metavar="TABLE.csv",
                        help="sensor table: header with x and y (or x_mm, y_mm, ...), and column (1-based) and/or id")
    parser.add_argument("--out", required=True, metavar="DIR", help="dataset folder to write")
    parser.add_argument("--period", type=positive_float, required=True, help="sampling period, s (row k is at k·period)")
    parser.add_argument("--columns", type=_columns, metavar="LIST",
                        help="matrix columns that are sensors, 1-based, e.g. 1-43 (default: the table's)")
    parser.add_argument("--header-lines", type=int_at_least(0), default=0, metavar="N",
                        help="lines to skip at the top of MATRIX (default: %(default)s)")
    parser.add_argument("--sensor-units", choices=tuple(METRES_PER),
                        help="unit of the table's x, y (default: the suffix of its field names, e.g. x_mm)")
    parser.add_argument("--range", type=positive_float, required=True, metavar="M",
                        help="sensing (footprint) radius, m, as the hardware states it")
    parser.add_argument("--pd", type=_probability, help="detection probability per sample to state for every sensor (default: none)")
    parser.add_argument("--pfa", type=_probability, help="false-alarm probability per sample to state for every sensor (default: none)")
    parser.add_argument("--region", type=area_type, metavar="XMIN,YMIN,XMAX,YMAX",
                        help="surveillance region, m (default: the sensors' bounding box grown by the range)")
    parser.add_argument("--name", help="deployment name (default: the name of DIR)")
    parser.add_argument("--floor-plan", metavar="PLAN.json",
                        help="the room's obstacles and doors, metres on the sensor table's axes (README, "
                        "\"Real sensors\"): no report is placed inside an obstacle, people are born near the doors")
    parser.add_argument("--truth", metavar="GT.xml", help="ground truth in CVML XML: box centres are positions")
    parser.add_argument("--truth-scale", type=positive_float, default=1.0, metavar="S",
                        help="CVML units per --truth-units, e.g. 25 for 25 mm (default: %(default)s)")
    parser.add_argument("--truth-units", choices=tuple(METRES_PER), default="m",
                        help="length unit of the CVML positions times --truth-scale (default: %(default)s)")
    parser.add_argument("--first-frame", type=int, default=1, metavar="N",
                        help="CVML frame number of the matrix's first row (default: %(default)s)")


def run(args: argparse.Namespace) -> int:
    sensors = read_sensor_table(args.sensors, args.sensor_units, args.columns)
    matrix = read_sample_matrix(args.matrix, args.header_lines)
    events = list(matrix_events(matrix, sensors, args.period, args.matrix))
    plan = read_floor_plan(args.floor_plan) if args.floor_plan else None
    if args.region is not None:
        xmin, ymin, xmax, ymax = args.region
    else:
        xs, ys = [s.x for s in sensors], [s.y for s in sensors]
        xmin, ymin, xmax, ymax = min(xs) - args.range, min(ys) - args.range, max(xs) + args.range, max(ys) + args.range
    try:
        deployment = Deployment(
            name=args.name or Path(args.out).resolve().name, units="m",
            region=Region(xmin=xmin, ymin=ymin, xmax=xmax, ymax=ymax),
            sensors=[DiskSensor(id=s.id, x=round(s.x, 6), y=round(s.y, 6), range=args.range, period=args.period,
                                pd=args.pd, pfa=args.pfa)
                     for s in sensors],
            floor_plan=plan)
    except ValidationError as exc:  # the floor plan's doors against the region
        raise CommandError(f"{args.floor_plan or args.sensors}: {exc.errors()[0]['msg'].removeprefix('Value error, ')}") from None
    truth = None
    if args.truth:
        truth = read_cvml(args.truth, args.period, args.truth_scale * METRES_PER[args.truth_units], args.first_frame)
    out = output_folder(Path(args.out))  # inputs first: a refused run leaves no folder behind
    try:
        write_dataset(out, deployment, events, truth)
    except OSError as exc:
        raise CommandError(f"cannot write {out}: {exc.strerror or exc}") from None
    duration = (matrix.shape[0] - 1) * args.period
    targets = len({r.target for r in truth}) if truth else 0
    print(f"{len(sensors)} sensors, {matrix.shape[0]} samples ({duration:g} s), {len(events)} transitions"
          + (f", {len(truth)} truth rows of {targets} targets" if truth else "") + f" written to {out}", file=sys.stderr)
    return 0
