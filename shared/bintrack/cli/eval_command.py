"""``bintrack eval DIR RESULT [--plot PNG]``: score a result (tracks.csv or objects.csv) against
the dataset's truth.csv and print the figures (:mod:`bintrack.evaluation.eval_report`)."""

from __future__ import annotations

import argparse
import json

from bintrack.argtypes import area_type, output_file, positive_float
from bintrack.errors import CommandError
from bintrack.evaluation.clear_mot import MATCHINGS
from bintrack.evaluation.eval_report import DEFAULT_GOSPA_C, DEFAULT_HIT, evaluate
from bintrack.formats import open_dataset


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dir", metavar="DIR", help="dataset folder (deployment.json, events.csv, truth.csv)")
    parser.add_argument("result", metavar="RESULT", help="tracks.csv or objects.csv to score")
    parser.add_argument("--plot", metavar="PNG", help="also write a PNG of sensors, detections, tracks and truth")
    parser.add_argument("--gospa-c", type=positive_float, default=DEFAULT_GOSPA_C, metavar="C",
                        help=f"GOSPA cut-off in the dataset's units (default {DEFAULT_GOSPA_C:g})")
    parser.add_argument("--hit", type=positive_float, metavar="D",
                        help=f"CLEAR MOT hit threshold in the dataset's units (default {DEFAULT_HIT:g} m)")
    parser.add_argument("--matching", choices=MATCHINGS, default="greedy",
                        help="CLEAR MOT pairing of the unmatched targets and tracks each frame: greedy (closest pair first, "
                        "as Milan et al. score) or hungarian (optimal); default %(default)s")
    parser.add_argument("--area", type=area_type, metavar="XMIN,YMIN,XMAX,YMAX",
                        help="score only targets and tracks inside this tracking area, dataset units")
    parser.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    parser.add_argument("--online", metavar="OBJECTS.csv",
                        help="also score this objects.csv (bintrack track --online: each object as first estimated) "
                        "and print its figures beside RESULT's (the final estimates); JSON: {\"final\": …, \"online\": …}")

def run(args: argparse.Namespace) -> int:
    dataset = open_dataset(args.dir)
    if args.plot:
        output_file(args.plot, what="plot")
    evaluation = evaluate(dataset, args.result, gospa_c=args.gospa_c, hit=args.hit, matching=args.matching,
                          area=args.area)
    online = None
    if args.online is not None:
        online = evaluate(dataset, args.online, gospa_c=args.gospa_c, hit=args.hit, matching=args.matching,
                          area=args.area)
        if evaluation.mode != "objects" or online.mode != "objects":
            raise CommandError("--online compares two objects.csv files (adaptive-basis); "
                               f"{args.result if evaluation.mode != 'objects' else args.online} is a tracks.csv")
    if args.json:
        print(json.dumps(evaluation.as_dict() if online is None else
                         {"final": evaluation.as_dict(), "online": online.as_dict()}))
    elif online is not None:
        print("\n".join(evaluation.beside(online, ("final", "online"))))
    else:
        print("\n".join(evaluation.lines()))
    if args.plot:
        from bintrack.evaluation.plotting import plot_evaluation  # matplotlib only when a plot is asked for

        try:
            written = plot_evaluation(args.plot, dataset, evaluation)
        except OSError as exc:
            raise CommandError(f"cannot write plot {args.plot}: {exc.strerror or exc}") from None
        if not args.json:
            print(f"plot written to {written}")
    return 0
