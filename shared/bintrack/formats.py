"""The files of DESIGN §6: a dataset folder (deployment.json, events.csv, truth.csv) and the
results (tracks.csv, objects.csv).

Events stream in event-time order without loading the whole file. Any malformed input raises
:class:`FormatError`, whose text is one line naming the file, the line and the field.
"""

from __future__ import annotations

import csv
import json
import math
import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, NamedTuple, TextIO

from pydantic import ValidationError

from bintrack.errors import BintrackError
from bintrack.deployment_model import Deployment, DiskSensor, FloorPlan, LineSensor, MotionSensor, SectorSensor
from bintrack.message_codec import location_text

DEPLOYMENT_FILE = "deployment.json"
EVENTS_FILE = "events.csv"
TRUTH_FILE = "truth.csv"

EVENTS_HEADER = ("t", "sensor", "value")
TRUTH_HEADER = ("t", "target", "x", "y")
TRACKS_HEADER = ("t", "track", "x", "y", "vx", "vy")
OBJECTS_HEADER = ("object", "t_first", "t_last", "entry_x", "entry_y", "exit_x", "exit_y", "vx", "vy")


class FormatError(BintrackError, ValueError):
    """Malformed input file: ``str()`` is ``FILE:LINE: FIELD: what is wrong``."""

    def __init__(self, path: Path | str, line: int | None, field: str, message: str):
        self.path = str(path)
        self.line = line
        self.field = field
        self.message = message
        where = f"{self.path}:{line}" if line is not None else self.path
        super().__init__(f"{where}: {field}: {message}")


class Event(NamedTuple):
    """One row of events.csv: at event time ``t`` (s), ``sensor`` reported ``value``."""

    t: float
    sensor: str
    value: int


class TruthRow(NamedTuple):
    t: float
    target: str
    x: float
    y: float


class TrackRow(NamedTuple):
    """One row of tracks.csv: track position (units) and velocity (units/s). Either may be None
    (empty in the file), not both: velocity-only estimators (paper 002) give no position."""

    t: float
    track: int
    x: float | None
    y: float | None
    vx: float | None = None
    vy: float | None = None


class ObjectRow(NamedTuple):
    """One row of objects.csv: a line-sensor object's entry and exit on the region border."""

    object: int
    t_first: float
    t_last: float
    entry_x: float
    entry_y: float
    exit_x: float
    exit_y: float
    vx: float
    vy: float


# --------------------------------------------------------------------------- numbers


def fmt(value: float | None, digits: int = 6) -> str:
    """Fixed-point text of ``value`` with trailing zeros trimmed ('' for None); deterministic."""
    if value is None:
        return ""
    text = f"{value:.{digits}f}"
    if "." in text:
        text = text.rstrip("0").rstrip(".")
    if text in ("-0", ""):
        text = "0"
    return text


def _parse_float(text: str, path: Path, line: int, field: str) -> float:
    if text.strip() == "":
        raise FormatError(path, line, field, "missing value")
    try:
        value = float(text)
    except ValueError:
        raise FormatError(path, line, field, f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise FormatError(path, line, field, f"not a finite number: {text!r}")
    return value


def _parse_optional_float(text: str, path: Path, line: int, field: str) -> float | None:
    return None if text.strip() == "" else _parse_float(text, path, line, field)


def _parse_int(text: str, path: Path, line: int, field: str) -> int:
    value = _parse_float(text, path, line, field)
    if value != int(value):
        raise FormatError(path, line, field, f"not an integer: {text!r}")
    return int(value)


# --------------------------------------------------------------------------- opening inputs


def open_input(path: Path | str, expected: str, binary: bool = False) -> IO:
    """Open an input file for reading; a missing file, a folder or an unreadable file raises
    :class:`FormatError` naming it (``expected`` says what should be there, e.g. "tracks.csv")."""
    path = Path(path)
    try:
        return open(path, "rb") if binary else open(path, newline="", encoding="utf-8")
    except FileNotFoundError:
        raise FormatError(path, None, "file", "not found") from None
    except IsADirectoryError:
        raise FormatError(path, None, "file", f"is a folder, expected {expected}") from None
    except OSError as exc:
        raise FormatError(path, None, "file", exc.strerror or str(exc)) from None


# --------------------------------------------------------------------------- CSV plumbing


def _rows(path: Path, header: tuple[str, ...], required: tuple[str, ...] | None = None) -> Iterator[tuple[int, dict[str, str]]]:
    """Yield (line number, row) for a CSV file with ``header``; checks header and row widths.

    ``required`` columns must be present (default: all of ``header``); others may be missing.
    """
    required = header if required is None else required
    with open_input(path, f"a CSV file with header {','.join(header)}") as handle:
        reader = csv.reader(handle)
        try:
            columns = next(reader)
        except StopIteration:
            raise FormatError(path, 1, "header", f"empty file, expected header {','.join(header)}") from None
        except (csv.Error, UnicodeDecodeError) as exc:
            raise FormatError(path, 1, "header", str(exc)) from None
        columns = [c.strip() for c in columns]
        missing = [c for c in required if c not in columns]
        if missing:
            raise FormatError(path, 1, missing[0], f"missing column (header must be {','.join(header)})")
        try:
            for fields in reader:
                line = reader.line_num
                if not fields or (len(fields) == 1 and fields[0].strip() == ""):
                    continue
                if len(fields) != len(columns):
                    short = len(fields) < len(columns)
                    name = columns[len(fields)] if short else "row"
                    what = "truncated row" if short else "too many fields"
                    raise FormatError(path, line, name, f"{what}: {len(fields)} fields, header has {len(columns)}")
                yield line, dict(zip(columns, fields))
        except (csv.Error, UnicodeDecodeError) as exc:
            raise FormatError(path, reader.line_num, "row", str(exc)) from None


def _write_csv(target: Path | str | TextIO, header: tuple[str, ...], rows: Iterable[Iterable[str]]) -> int:
    """Write a CSV to a text stream, or atomically to a path (temporary file, then rename).

    Returns the number of rows written.
    """
    if hasattr(target, "write"):
        return _write_rows(target, header, rows)
    path = Path(target)
    tmp = path.with_name(path.name + ".tmp")
    try:
        with open(tmp, "w", newline="", encoding="utf-8") as handle:
            count = _write_rows(handle, header, rows)
        tmp.replace(path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return count


def _write_rows(handle: TextIO, header: tuple[str, ...], rows: Iterable[Iterable[str]]) -> int:
    writer = csv.writer(handle, lineterminator="\n")
    writer.writerow(header)
    count = 0
    for row in rows:
        writer.writerow(row)
        count += 1
    return count


# --------------------------------------------------------------------------- deployment


def _sensor_lines(text: str) -> list[int]:
    """Line number of each element of the top-level ``sensors`` array (best effort)."""
    match = re.search(r'"sensors"\s*:\s*\[', text)
    if not match:
        return []
    decoder = json.JSONDecoder()
    pos = match.end()
    lines = []
    while True:
        while pos < len(text) and text[pos] in " \t\r\n,":
            pos += 1
        if pos >= len(text) or text[pos] == "]":
            return lines
        lines.append(text.count("\n", 0, pos) + 1)
        try:
            _, pos = decoder.raw_decode(text, pos)
        except json.JSONDecodeError:
            return lines


def _read_text(path: Path, expected: str) -> str:
    """The text of an input file (``expected`` as :func:`open_input`); raises :class:`FormatError`."""
    with open_input(path, expected) as handle:
        try:
            return handle.read()
        except UnicodeDecodeError as exc:
            raise FormatError(path, None, "file", str(exc)) from None


def _json_object(text: str, path: Path | str, what: str) -> dict:
    """``text`` parsed as a JSON object (``what`` it should be, for the message); raises :class:`FormatError`."""
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise FormatError(path, exc.lineno, "json", exc.msg) from None
    except RecursionError:
        raise FormatError(path, None, "json", f"nested too deeply to be {what}") from None
    if not isinstance(data, dict):
        raise FormatError(path, 1, "(top level)", "expected a JSON object")
    return data


def parse_deployment(text: str, path: Path | str = DEPLOYMENT_FILE) -> Deployment:
    """Parse deployment.json text; raises :class:`FormatError` naming line and field."""
    data = _json_object(text, path, "a deployment")
    fmt_tag = data.get("format")
    if fmt_tag is None:
        raise FormatError(path, 1, "format", "missing field (expected 'bintrack.deployment/1')")
    if fmt_tag != "bintrack.deployment/1":
        raise FormatError(path, 1, "format", f"unsupported format {fmt_tag!r} (expected 'bintrack.deployment/1')")
    data.pop("version", None)
    try:
        return Deployment.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = err["loc"]
        line = 1
        if len(loc) >= 2 and loc[0] == "sensors" and isinstance(loc[1], int):
            lines = _sensor_lines(text)
            if loc[1] < len(lines):
                line = lines[loc[1]]
        message = err["msg"]
        if err["type"] == "missing":
            message = "missing field"
        elif err["type"] == "union_tag_invalid":
            message = "unknown sensor kind (expected disk, sector, motion or line)"
        return_field = location_text(loc)
        if err["type"] == "union_tag_invalid":
            return_field += ".kind"
        raise FormatError(path, line, return_field, message) from None


def read_deployment(path: Path | str) -> Deployment:
    """Read and validate a deployment.json file."""
    path = Path(path)
    return parse_deployment(_read_text(path, DEPLOYMENT_FILE), path)


def read_floor_plan(path: Path | str) -> FloorPlan:
    """Read and validate a floor plan: a JSON object with ``obstacles`` (areas: ``xmin``, ``ymin``,
    ``xmax``, ``ymax`` or ``polygon``, not crossing itself) and ``doors`` ([x, y] each), deployment
    units; raises :class:`FormatError` naming the field."""
    path = Path(path)
    data = _json_object(_read_text(path, "floor plan"), path, "a floor plan")
    try:
        plan = FloorPlan.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        raise FormatError(path, None, location_text(err["loc"]), err["msg"].removeprefix("Value error, ")) from None
    from bintrack.floor_plan import FloorShape  # shapely: only where a plan is read

    try:
        FloorShape(plan)
    except ValueError as exc:
        raise FormatError(path, None, "obstacles", str(exc)) from None
    return plan


def deployment_text(deployment: Deployment) -> str:
    """Canonical JSON text of a deployment (stable key order, for byte-identical datasets)."""
    data = deployment.model_dump(mode="json", by_alias=True, exclude_none=True)
    data.pop("version", None)
    for sensor in data["sensors"]:
        for key in ("clock_offset", "clock_skew"):
            if sensor.get(key) == 0.0:
                del sensor[key]
    ordered = {"format": data.pop("format"), "name": data.pop("name"), "units": data.pop("units"),
               "region": data.pop("region")}
    ordered.update(data)
    return json.dumps(ordered, indent=1) + "\n"


def write_deployment(path: Path | str, deployment: Deployment) -> None:
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(deployment_text(deployment), encoding="utf-8")
    tmp.replace(path)


# --------------------------------------------------------------------------- values by kind


def check_value(sensor, value: int) -> str | None:
    """Why ``value`` does not fit ``sensor``'s kind (DESIGN §6), or None if it fits."""
    if isinstance(sensor, SectorSensor):
        if not -1 <= value < sensor.sectors:
            return f"sector sensor with {sensor.sectors} sectors reports -1..{sensor.sectors - 1}, got {value}"
    elif isinstance(sensor, DiskSensor):
        if value not in (0, 1):
            return f"disk sensor reports 0 or 1, got {value}"
    elif isinstance(sensor, MotionSensor):
        if value not in (-1, 1):
            return f"motion sensor reports +1 or -1, got {value}"
    elif isinstance(sensor, LineSensor):
        if value != 1:
            return f"line sensor reports 1 (beam crossed), got {value}"
    return None


def idle_value(sensor) -> int:
    """The status a sensor has before its first report: absent (0, or -1 for sector/motion)."""
    if isinstance(sensor, (SectorSensor, MotionSensor)):
        return -1
    return 0


# --------------------------------------------------------------------------- dataset


@dataclass(frozen=True)
class Dataset:
    """A dataset folder: deployment, a stream of events, and truth if present."""

    path: Path
    deployment: Deployment

    @property
    def events_path(self) -> Path:
        return self.path / EVENTS_FILE

    @property
    def truth_path(self) -> Path:
        return self.path / TRUTH_FILE

    @property
    def has_truth(self) -> bool:
        return self.truth_path.exists()

    def events(self) -> Iterator[Event]:
        """Stream events.csv in event-time order, validating every row."""
        return iter_events(self.events_path, self.deployment)

    def truth(self) -> list[TruthRow]:
        return read_truth(self.truth_path)


def open_dataset(path: Path | str) -> Dataset:
    """Open a dataset folder and validate its deployment.json (events are read lazily)."""
    path = Path(path)
    if not path.is_dir():
        raise FormatError(path, None, "dataset", "not a folder")
    deployment = read_deployment(path / DEPLOYMENT_FILE)
    if not (path / EVENTS_FILE).exists():
        raise FormatError(path / EVENTS_FILE, None, "file", "not found")
    return Dataset(path=path, deployment=deployment)


def iter_events(path: Path | str, deployment: Deployment) -> Iterator[Event]:
    """Yield validated events from events.csv one row at a time (constant memory)."""
    path = Path(path)
    sensors = deployment.by_id()
    last_t = -math.inf
    for line, row in _rows(path, EVENTS_HEADER):
        t = _parse_float(row["t"], path, line, "t")
        if t < last_t:
            raise FormatError(path, line, "t", f"time {row['t']} is earlier than the previous row's {fmt(last_t, 9)}")
        last_t = t
        sensor_id = row["sensor"].strip()
        if sensor_id == "":
            raise FormatError(path, line, "sensor", "missing value")
        sensor = sensors.get(sensor_id)
        if sensor is None:
            raise FormatError(path, line, "sensor", f"unknown sensor id {sensor_id!r} (not in deployment.json)")
        value = _parse_int(row["value"], path, line, "value")
        problem = check_value(sensor, value)
        if problem:
            raise FormatError(path, line, "value", problem)
        yield Event(t, sensor_id, value)


def write_events(path: Path | str, events: Iterable[Event]) -> int:
    """Write events.csv (rows must already be in time order); times with ns resolution."""
    return _write_csv(Path(path), EVENTS_HEADER, ((fmt(e.t, 9), e.sensor, str(int(e.value))) for e in events))


def read_truth(path: Path | str) -> list[TruthRow]:
    """Read truth.csv; rows are returned sorted by (target, t)."""
    path = Path(path)
    rows = []
    for line, row in _rows(path, TRUTH_HEADER):
        target = row["target"].strip()
        if target == "":
            raise FormatError(path, line, "target", "missing value")
        rows.append(
            TruthRow(
                _parse_float(row["t"], path, line, "t"),
                target,
                _parse_float(row["x"], path, line, "x"),
                _parse_float(row["y"], path, line, "y"),
            )
        )
    rows.sort(key=lambda r: (r.target, r.t))
    return rows


def write_truth(path: Path | str, rows: Iterable[TruthRow]) -> int:
    return _write_csv(Path(path), TRUTH_HEADER, ((fmt(r.t, 6), r.target, fmt(r.x), fmt(r.y)) for r in rows))


def write_dataset(path: Path | str, deployment: Deployment, events: Iterable[Event],
                  truth: Iterable[TruthRow] | None = None) -> Path:
    """Write a complete dataset folder (created if needed)."""
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    write_deployment(path / DEPLOYMENT_FILE, deployment)
    write_events(path / EVENTS_FILE, events)
    if truth is not None:
        write_truth(path / TRUTH_FILE, truth)
    return path


# --------------------------------------------------------------------------- results


def write_tracks(target: Path | str | TextIO, rows: Iterable[TrackRow]) -> int:
    """Write tracks.csv (t in s, positions in units, velocities in units/s or empty) to a path or stream."""
    return _write_csv(
        target,
        TRACKS_HEADER,
        ((fmt(r.t, 9), str(r.track), fmt(r.x), fmt(r.y), fmt(r.vx), fmt(r.vy)) for r in rows),
    )


def read_tracks(path: Path | str) -> list[TrackRow]:
    path = Path(path)
    rows = []
    for line, row in _rows(path, TRACKS_HEADER, required=("t", "track", "x", "y")):
        parsed = TrackRow(
            _parse_float(row["t"], path, line, "t"),
            _parse_int(row["track"], path, line, "track"),
            _parse_optional_float(row.get("x", ""), path, line, "x"),
            _parse_optional_float(row.get("y", ""), path, line, "y"),
            _parse_optional_float(row.get("vx", ""), path, line, "vx"),
            _parse_optional_float(row.get("vy", ""), path, line, "vy"),
        )
        for a, b in (("x", "y"), ("vx", "vy")):
            if (getattr(parsed, a) is None) != (getattr(parsed, b) is None):
                raise FormatError(path, line, b if getattr(parsed, b) is None else a, f"empty while {a if getattr(parsed, b) is None else b} is given")
        if parsed.x is None and parsed.vx is None:
            raise FormatError(path, line, "x", "a row needs a position (x, y), a velocity (vx, vy) or both")
        rows.append(parsed)
    return rows


def write_objects(target: Path | str | TextIO, rows: Iterable[ObjectRow]) -> int:
    """Write objects.csv (times in s, points in units, velocity in units/s) to a path or stream."""
    return _write_csv(
        target,
        OBJECTS_HEADER,
        ((str(r.object), fmt(r.t_first, 9), fmt(r.t_last, 9)) + tuple(fmt(v) for v in r[3:]) for r in rows),
    )


def read_objects(path: Path | str) -> list[ObjectRow]:
    path = Path(path)
    rows = []
    for line, row in _rows(path, OBJECTS_HEADER):
        rows.append(
            ObjectRow(
                _parse_int(row["object"], path, line, "object"),
                *(_parse_float(row[name], path, line, name) for name in OBJECTS_HEADER[1:]),
            )
        )
    return rows
