"""The evaluation report of ``bintrack eval DIR RESULT``: a result (tracks.csv or objects.csv) scored
against truth.csv.

Which figures apply depends on the result and the truth:

* tracks.csv, one target and at most one track id: location error and error/R (paper 001
  §5.3), trajectory error (§5.5), velocity error when the rows carry a velocity (§5.4);
* tracks.csv with several targets or several track ids: GOSPA per frame and its parts, the
  error in the number of targets, identity switches (paper 004), CLEAR MOT (MOTA, MOTP, FP, FN,
  mismatches; greedy or Hungarian pairing within a hit threshold) and IDF1
  (:mod:`.clear_mot`), and the location error to the nearest target. Frames are the result's
  times and, for sampled sensors, every sampling instant within the truth's span, so that a
  frame without tracks counts; an optional tracking area leaves out what lies outside it;
* objects.csv: entry and exit point errors of line-sensor objects (paper 003 §7.2).
"""

from __future__ import annotations

import csv
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from bintrack.evaluation import metrics
from bintrack.evaluation.clear_mot import Frame, clear_mot
from bintrack.errors import CommandError
from bintrack.formats import (
    OBJECTS_HEADER,
    TRACKS_HEADER,
    Dataset,
    FormatError,
    ObjectRow,
    TrackRow,
    fmt,
    open_dataset,
    open_input,
    read_objects,
    read_tracks,
)

DEFAULT_GOSPA_C = 10.0
DEFAULT_HIT = 1.5
"""CLEAR MOT hit threshold, m (Milan et al.'s for people on the floor)"""

class Figure(NamedTuple):
    """One figure of an evaluation: ``key`` in :meth:`Evaluation.as_dict`, a human ``label``,
    the ``value`` (None when it cannot be computed) and its ``unit`` ('' when unitless)."""

    key: str
    label: str
    value: float | int | None
    unit: str = ""

class Series(NamedTuple):
    """An error over time for the plot's second panel: times (s) and errors (units), drawn
    as a line when ``joined`` (errors of one track) or as separate points (one per object)."""

    label: str
    t: np.ndarray
    values: np.ndarray
    joined: bool = True

@dataclass(frozen=True, eq=False)
class Evaluation:
    """The figures of one result against one dataset's truth, and what the plot needs.

    ``kind`` is 'tracks' or 'objects'; ``mode`` is 'single' (one target, one track),
    'multi' (several targets or tracks) or 'objects'. ``main`` holds the keys of the headline
    figures.
    """

    dataset: Path
    result: Path
    kind: str
    mode: str
    units: str
    figures: tuple[Figure, ...]
    main: tuple[str, ...]
    tracks: tuple[TrackRow, ...]
    objects: tuple[ObjectRow, ...]
    truth: Mapping[str, metrics.TruthPath]
    series: tuple[Series, ...]

    def value(self, key: str) -> float | int | None:
        """The value of the figure ``key``; KeyError if this evaluation has no such figure."""
        for figure in self.figures:
            if figure.key == key:
                return figure.value
        raise KeyError(key)

    def headline(self) -> str:
        """The main figures as one short text, e.g. 'GOSPA (c = 10 m), mean 2.31 m'."""
        figures = [f for key in self.main for f in self.figures if f.key == key]
        return "; ".join(f"{f.label} {_text(f.value)}{' ' + f.unit if f.unit else ''}" for f in figures)

    def lines(self) -> list[str]:
        """An aligned human-readable table: what was scored, then one figure per line."""
        head = [("dataset", str(self.dataset)), ("result", f"{self.result} ({_MODE_TEXT[self.mode]})")]
        values = [_text(f.value) for f in self.figures]
        label_width = max(len(label) for label in [f.label for f in self.figures] + [h for h, _ in head])
        value_width = max(len(v) for v in values)
        out = [f"{label:<{label_width}}  {text}" for label, text in head]
        for figure, text in zip(self.figures, values):
            out.append(f"{figure.label:<{label_width}}  {text:>{value_width}} {figure.unit}".rstrip())
        return out

    def beside(self, other: "Evaluation", names: tuple[str, str]) -> list[str]:
        """This evaluation's figures and ``other``'s (the same kind of result scored the same
        way) in two columns headed ``names``, e.g. ('final', 'online')."""
        head = [("dataset", str(self.dataset)), (f"result, {names[0]}", f"{self.result} ({_MODE_TEXT[self.mode]})"),
                (f"result, {names[1]}", f"{other.result} ({_MODE_TEXT[other.mode]})")]
        labels = [f.label for f in self.figures]
        width = max(len(label) for label in labels + [h for h, _ in head])
        cells = [(_text(a.value), _text(b.value)) for a, b in zip(self.figures, other.figures)]
        value_width = max(len(v) for pair in cells for v in pair + names)
        out = [f"{label:<{width}}  {text}" for label, text in head]
        out.append(f"{'':<{width}}  {names[0]:>{value_width}} {names[1]:>{value_width}}")
        for figure, (a, b) in zip(self.figures, cells):
            out.append(f"{figure.label:<{width}}  {a:>{value_width}} {b:>{value_width}} {figure.unit}".rstrip())
        return out

    def as_dict(self) -> dict:
        """The figures keyed by ``Figure.key`` after dataset, result, kind, mode and units;
        JSON-ready (None where a figure cannot be computed)."""
        out: dict = {"dataset": str(self.dataset), "result": str(self.result), "kind": self.kind,
                     "mode": self.mode, "units": self.units}
        out.update((figure.key, figure.value) for figure in self.figures)
        return out

_MODE_TEXT = {"single": "single-target tracks", "multi": "multi-target tracks", "objects": "line-sensor objects"}

def _text(value: float | int | None) -> str:
    if value is None:
        return "n/a"
    if isinstance(value, int):
        return str(value)
    return fmt(float(value), 4)

# --------------------------------------------------------------------------- reading the result

def read_result(path: Path | str) -> tuple[str, list[TrackRow] | list[ObjectRow]]:
    """Read RESULT as tracks.csv or objects.csv, told apart by the header: ('tracks', rows)
    or ('objects', rows). Raises :class:`FormatError` for anything malformed."""
    path = Path(path)
    try:
        with open_input(path, "tracks.csv or objects.csv") as handle:
            header = next(csv.reader(handle), None)
    except (csv.Error, UnicodeDecodeError) as exc:
        raise FormatError(path, 1, "header", str(exc)) from None
    columns = [c.strip() for c in header or ()]
    if "object" in columns:
        return "objects", read_objects(path)
    if "track" in columns:
        return "tracks", read_tracks(path)
    expected = f"{','.join(TRACKS_HEADER)} (tracks.csv) or {','.join(OBJECTS_HEADER)} (objects.csv)"
    what = "empty file" if header is None else "unknown header"
    raise FormatError(path, 1, "header", f"{what}, expected {expected}")

# --------------------------------------------------------------------------- scoring

def evaluate(dataset: Dataset | Path | str, result_path: Path | str, *, gospa_c: float = DEFAULT_GOSPA_C,
             hit: float | None = None, matching: str = "greedy",
             area: tuple[float, float, float, float] | None = None) -> Evaluation:
    """Score the result file ``result_path`` against ``dataset``'s truth.csv.

    ``gospa_c`` is GOSPA's cut-off in the dataset's units (p = 2, α = 2). Multi-target results
    also get CLEAR MOT (:mod:`.clear_mot`) with hit threshold ``hit`` (units; default 1.5 m in
    the dataset's units) and ``matching`` ("greedy" or "hungarian"). With ``area`` (xmin, ymin,
    xmax, ymax, units) targets and tracks outside it are left out of the multi-target scores, as
    Milan et al. score only the tracking area. Raises
    :class:`CommandError` when there is no truth to score against and :class:`FormatError`
    for a malformed file.
    """
    if not isinstance(dataset, Dataset):
        dataset = open_dataset(dataset)
    if not dataset.has_truth:
        raise CommandError(f"no truth.csv in {dataset.path}: nothing to score against")
    truth = metrics.truth_paths(dataset.truth())
    if not truth:
        raise CommandError(f"{dataset.truth_path} has no rows: nothing to score against")
    kind, rows = read_result(result_path)
    units = dataset.deployment.units
    common = dict(dataset=dataset.path, result=Path(result_path), kind=kind, units=units, truth=truth)
    if kind == "objects":
        figures, series = _object_figures(rows, truth, units)
        return Evaluation(mode="objects", figures=figures, main=("entry_error_mean", "exit_error_mean"), tracks=(), objects=tuple(rows),
                          series=series, **common)
    R = metrics.sensing_range(dataset.deployment)
    if len(truth) == 1 and len({r.track for r in rows}) <= 1:
        figures, series = _single_figures(rows, next(iter(truth.values())), R, units)
        if all(r.x is None for r in rows):
            main = ("heading_error_mean", "speed_error_mean")
        else:
            main = ("location_error_over_R_mean",) if R is not None else ("location_error_mean",)
        return Evaluation(mode="single", figures=figures, main=main, tracks=tuple(rows), objects=(), series=series,
                          **common)
    if hit is None:
        hit = DEFAULT_HIT / dataset.deployment.metres_per_unit
    frames = _frames(rows, truth, dataset.deployment, area)
    figures, series = _multi_figures(rows, truth, R, units, gospa_c, frames, hit, matching)
    return Evaluation(mode="multi", figures=figures, main=("gospa_mean", "mota"), tracks=tuple(rows), objects=(), series=series,
                      **common)

def _location_figures(rows, truth, R, units, to: str) -> tuple[list[Figure], Series]:
    errors = metrics.location_errors(rows, truth)
    stats = metrics.ErrorStats.of(errors)
    figures = [
        Figure("rows", "rows in the result", len(rows)),
        Figure("rows_scored", f"rows while {to} exists", stats.n),
        Figure("location_error_mean", f"location error to {to}, mean", stats.mean, units),
        Figure("location_error_median", f"location error to {to}, median", stats.median, units),
        Figure("location_error_max", f"location error to {to}, max", stats.max, units),
    ]
    if R is not None:
        figures.append(Figure("sensing_range", "sensing range R (median)", R, units))
        for name in ("mean", "median", "max"):
            value = getattr(stats, name)
            figures.append(Figure(f"location_error_over_R_{name}", f"location error / R, {name}",
                                  None if value is None else value / R))
    scored = ~np.isnan(errors)
    times = np.array([r.t for r in rows], dtype=float)
    return figures, Series(f"location error ({units})", times[scored], errors[scored])

def _single_figures(rows, path: metrics.TruthPath, R, units) -> tuple[tuple[Figure, ...], tuple[Series, ...]]:
    """Location figures over the rows with a position, trajectory error, and velocity, heading
    and speed errors over the rows with a velocity (velocity-only estimators have no position)."""
    placed = [r for r in rows if r.x is not None]
    figures, series = _location_figures(placed, {path.target: path}, R, units, "the target")
    figures[0] = Figure("rows", "rows in the result", len(rows))
    figures.append(Figure("trajectory_error", "trajectory error (area / length)",
                          metrics.trajectory_error(placed, path) if len(placed) >= 2 else None, units))
    if any(r.vx is not None and r.vy is not None for r in rows):
        stats = metrics.ErrorStats.of(metrics.velocity_errors(rows, path))
        heading, speed = metrics.heading_speed_errors(rows, path)
        heading_stats, speed_stats = metrics.ErrorStats.of(np.degrees(heading)), metrics.ErrorStats.of(100 * speed)
        figures += [
            Figure("velocity_rows", "rows with a velocity, scored", stats.n),
            Figure("velocity_error_mean", "velocity error, mean", stats.mean, f"{units}/s"),
            Figure("velocity_error_max", "velocity error, max", stats.max, f"{units}/s"),
            Figure("heading_error_mean", "heading error, mean", heading_stats.mean, "deg"),
            Figure("heading_error_median", "heading error, median", heading_stats.median, "deg"),
            Figure("speed_error_mean", "speed error, mean", speed_stats.mean, "%"),
            Figure("speed_error_median", "speed error, median", speed_stats.median, "%"),
        ]
        if not placed:  # a velocity-only estimator: plot its heading error instead
            timed = [r for r in rows if r.vx is not None and path.exists(r.t)]
            heading_all, _ = metrics.heading_speed_errors(timed, path)
            if len(heading_all) == len(timed):
                series = Series("heading error (deg)", np.array([r.t for r in timed]), np.degrees(heading_all))
    return tuple(figures), (series,)

def _frames(rows, truth, deployment, area) -> list[Frame]:
    """The multi-target frames: every time of ``rows`` and, where the sensors are sampled every
    P s, every k·P within the truth's time span (so that a frame without tracks counts), with
    the targets existing then and the tracks of that time, both inside ``area`` if given."""
    times = {r.t for r in rows}
    periods = [s.period for s in deployment.sensors if getattr(s, "period", None)]
    if periods:
        period = max(periods)
        start = min(p.start for p in truth.values())
        end = max(p.end for p in truth.values())
        k0, k1 = int(np.ceil(start / period - 1e-9)), int(np.floor(end / period + 1e-9))
        times.update(round(k * period, 9) for k in range(k0, k1 + 1))
    by_time: dict[float, list[TrackRow]] = {}
    for r in rows:
        if r.x is not None:
            by_time.setdefault(r.t, []).append(r)

    def inside(x, y) -> bool:
        return area is None or (area[0] <= x <= area[2] and area[1] <= y <= area[3])

    frames = []
    for t in sorted(times):
        targets, txy = [], []
        for k, path in truth.items():
            if path.exists(t):
                x, y = path.position(t)
                if inside(x, y):
                    targets.append(k)
                    txy.append((x, y))
        tracks = [r for r in sorted(by_time.get(t, []), key=lambda r: r.track) if inside(r.x, r.y)]
        frames.append(Frame(t, tuple(targets), np.array(txy, dtype=float).reshape(-1, 2),
                            tuple(r.track for r in tracks), np.array([(r.x, r.y) for r in tracks], dtype=float).reshape(-1, 2)))
    return frames


def _multi_figures(rows, truth, R, units, c: float, frames: list[Frame], hit: float,
                   matching: str) -> tuple[tuple[Figure, ...], tuple[Series, ...]]:
    switches = metrics.multi_target_scores(rows, truth, c).identity_switches
    scans = tuple(metrics.Scan(f.t, metrics.gospa(f.track_xy, f.target_xy, c), len(f.tracks), len(f.targets))
                  for f in frames)
    scores = metrics.MultiTargetScores(c, 2.0, scans, switches)
    mot = clear_mot(frames, hit, matching)
    figures = [
        Figure("targets", "targets in truth", len(truth)),
        Figure("tracks", "track ids in the result", len({r.track for r in rows})),
        Figure("scans", "scans (distinct times)", len(scores.scans)),
        Figure("gospa_c", "GOSPA cut-off c (p = 2, alpha = 2)", c, units),
        Figure("gospa_mean", f"GOSPA (c = {fmt(c, 4)} {units}), mean", scores.gospa_mean, units),
        Figure("gospa_localisation_mean", "  localisation part, mean", scores.localisation_mean, f"{units}^2"),
        Figure("gospa_missed_mean", "  missed part, mean", scores.missed_mean, f"{units}^2"),
        Figure("gospa_false_mean", "  false part, mean", scores.false_mean, f"{units}^2"),
        Figure("missed_targets_mean", "missed targets per scan, mean", scores.missed_targets_mean),
        Figure("false_tracks_mean", "false tracks per scan, mean", scores.false_tracks_mean),
        Figure("target_count_error_mean", "|tracks - targets| per scan, mean", scores.count_error_mean),
        Figure("target_count_correct", "scans with the right number", scores.count_correct),
        Figure("identity_switches", "identity switches", scores.identity_switches),
        Figure("hit_threshold", f"CLEAR MOT hit threshold ({matching} matching)", hit, units),
        Figure("frames", "CLEAR MOT frames", mot.frames),
        Figure("mota", "MOTA", mot.mota),
        Figure("motp", "MOTP (1 - mean distance / threshold)", mot.motp),
        Figure("motp_distance", "matched distance, mean", mot.motp_distance, units),
        Figure("recall", "recall", mot.recall),
        Figure("precision", "precision", mot.precision),
        Figure("false_positives", "false positives (FP)", mot.false_positives),
        Figure("misses", "misses (FN)", mot.misses),
        Figure("mismatches", "identity switches (CLEAR MOT)", mot.switches),
        Figure("idf1", "IDF1", mot.idf1),
    ]
    location, _ = _location_figures(rows, truth, R, units, "nearest target")
    figures += location[1:]  # the row count is already in the table
    gospa_series = Series(f"GOSPA ({units})", np.array([s.t for s in scores.scans]),
                          np.array([s.gospa.distance for s in scores.scans]))
    return tuple(figures), (gospa_series,)

def _object_figures(objects, truth, units) -> tuple[tuple[Figure, ...], tuple[Series, ...]]:
    errors = metrics.entry_exit_errors(objects, truth)
    entry = metrics.ErrorStats.of([e.entry for e in errors])
    exit_ = metrics.ErrorStats.of([e.exit for e in errors])
    figures = (
        Figure("objects", "objects in the result", len(objects)),
        Figure("targets", "targets in truth", len(truth)),
        Figure("objects_matched", "objects matched to a target", len(errors)),
        Figure("entry_error_mean", "entry point error, mean", entry.mean, units),
        Figure("entry_error_max", "entry point error, max", entry.max, units),
        Figure("exit_error_mean", "exit point error, mean", exit_.mean, units),
        Figure("exit_error_max", "exit point error, max", exit_.max, units),
    )
    by_object = {o.object: o for o in objects}
    series = (
        Series(f"entry error ({units})", np.array([by_object[e.object].t_first for e in errors]),
               np.array([e.entry for e in errors]), joined=False),
        Series(f"exit error ({units})", np.array([by_object[e.object].t_last for e in errors]),
               np.array([e.exit for e in errors]), joined=False),
    )
    return figures, series
