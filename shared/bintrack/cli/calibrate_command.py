"""``bintrack calibrate DATASET --out DIR``: fit each disk sensor's footprint radius, pd, pfa and
hold time to the recording (:mod:`bintrack.calibration.pir_calibration`) and write DIR, the same
dataset with the fitted deployment.json. From the detections alone unless ``--supervised``."""

from __future__ import annotations

import argparse
import collections
import shutil
import statistics
import sys
from pathlib import Path

import numpy as np

from bintrack.argtypes import int_at_least, output_folder, positive_float
from bintrack.cli.progress import Progress
from bintrack.calibration.pir_calibration import MIN_INTERVAL_SAMPLES, Estimate, Fit, calibrate, calibrate_supervised
from bintrack.calibration.sample_series import sample_series
from bintrack.errors import CommandError
from bintrack.formats import EVENTS_FILE, TRUTH_FILE, open_dataset, write_deployment
from bintrack.deployment_model import DiskSensor

PARAMETERS = (("range", "footprint radius", "units"), ("pd", "pd per sample", ""), ("pfa", "pfa per sample", ""),
              ("hold", "hold time", "s"), ("still", "pd standing still / pd", ""))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dataset", metavar="DATASET", help="dataset folder of disk sensors sampled every period")
    parser.add_argument("--out", required=True, metavar="DIR", help="folder to write: DATASET with the fitted deployment.json")
    parser.add_argument("--supervised", action="store_true",
                        help="fit to DATASET's truth.csv instead of the detections (for comparison)")
    parser.add_argument("--range", type=positive_float, metavar="R",
                        help="the stated footprint radius, units, the only prior (default: the deployment's median range)")
    parser.add_argument("--boot", type=int_at_least(0), default=100, metavar="N",
                        help="bootstrap resamples for the intervals (default: %(default)s; 0: none)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the bootstrap (default: %(default)s)")
    parser.add_argument("--sensors", action="store_true", help="also print every sensor's estimates")
    parser.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                        help="show the bootstrap's progress on stderr (default: when stderr is a terminal)")


def run(args: argparse.Namespace) -> int:
    dataset = open_dataset(args.dataset)
    out = Path(args.out)
    if out.resolve() == dataset.path.resolve():
        raise CommandError("--out must be another folder than DATASET")
    deployment = dataset.deployment
    disks = [s for s in deployment.sensors if isinstance(s, DiskSensor)]
    stated = args.range if args.range is not None else (statistics.median(s.range for s in disks) if disks else None)
    try:
        series = sample_series(deployment, dataset.events())
    except ValueError as exc:
        raise CommandError(f"{dataset.path}: {exc}") from None
    if args.supervised:
        if not dataset.has_truth:
            raise CommandError(f"--supervised needs {dataset.truth_path}, which does not exist")
        rows = collections.defaultdict(list)
        for r in dataset.truth():
            rows[r.target].append((r.t, r.x, r.y))
        truth = {k: (np.array([a[0] for a in v]), np.array([a[1:] for a in v])) for k, v in rows.items()}
        fit = calibrate_supervised(series, truth, max_range=5.0 * stated)
    else:
        progress = Progress("calibrate: bootstrap", args.boot, enabled=args.progress)
        try:
            fit = calibrate(series, stated, boot=args.boot, seed=args.seed,
                            progress=lambda done, total: progress.update(done, force=done == total))
        finally:
            progress.close()
        if args.boot and fit.pooled.range.low is None:
            print(f"calibrate: warning: only {len(series.status)} samples: too few for intervals (the bootstrap "
                  f"needs {MIN_INTERVAL_SAMPLES}), and the estimates rest on very little data", file=sys.stderr)
    by_id = {f.id: f for f in fit.sensors}
    sensors = []
    for s in deployment.sensors:
        f = by_id.get(s.id)
        if f is None:
            sensors.append(s)
            continue
        fields = dict(range=round(f.range.value, 4), pd=round(f.pd.value, 4), pfa=round(f.pfa.value, 5),
                      hold=round(f.hold.value, 4), range_in=None, detection_law=None)
        if f.still is not None:
            fields["still"] = round(f.still.value, 4)
        sensors.append(s.model_copy(update=fields))
    fitted = deployment.model_validate({**deployment.model_dump(by_alias=True), "sensors": [s.model_dump() for s in sensors]})
    out = output_folder(out)  # the fit first: a refused run leaves no folder behind
    try:
        write_deployment(out / "deployment.json", fitted)
        shutil.copyfile(dataset.events_path, out / EVENTS_FILE)
        if dataset.has_truth:
            shutil.copyfile(dataset.truth_path, out / TRUTH_FILE)
    except OSError as exc:
        raise CommandError(f"cannot write {out}: {exc.strerror or exc}") from None
    print("\n".join(report_lines(fit, deployment.units, len(series.status), series.period, args.sensors)))
    print(f"fitted deployment of {len(fit.sensors)} sensors written to {out}", file=sys.stderr)
    return 0


def _text(e: Estimate | None) -> str:
    if e is None:
        return "-"
    if e.low is None:
        return f"{e.value:.4g}"
    return f"{e.value:.4g} [{e.low:.4g}, {e.high:.4g}]"


def report_lines(fit: Fit, units: str, samples: int, period: float, per_sensor: bool) -> list[str]:
    """What was estimated and how sure: pooled value (95 % bootstrap interval), the median and
    quartiles over sensors, and, with ``per_sensor``, each sensor's estimates."""
    source = "the detections alone" if fit.method == "detections" else "the truth (supervised)"
    out = [f"fitted to {source}: {len(fit.sensors)} sensors, {samples} samples every {period:g} s"]
    pooled_label = "pooled (95 % interval)" if fit.method == "detections" else "median"
    out.append(f"{'parameter':<24} {pooled_label:<28} {'sensors: median [quartiles]'}")
    for key, label, unit in PARAMETERS:
        values = [getattr(f, key).value for f in fit.sensors if getattr(f, key) is not None]
        if not values:
            continue
        q1, q2, q3 = np.percentile(values, [25, 50, 75])
        u = units if unit == "units" else unit
        out.append(f"{label + (f' ({u})' if u else ''):<24} {_text(getattr(fit.pooled, key)):<28} {q2:.4g} [{q1:.4g}, {q3:.4g}]")
    if per_sensor:
        out.append(f"{'sensor':<8} " + " ".join(f"{k:<26}" for k, _, _ in PARAMETERS[:4]))
        for f in fit.sensors:
            out.append(f"{f.id:<8} " + " ".join(f"{_text(getattr(f, k)):<26}" for k, _, _ in PARAMETERS[:4]))
    return out
