"""A recording of binary sensors as a sample matrix (one row per sampling period, one column
per sensor) and a sensor table, read into DESIGN §6 events and a deployment.

Matrix: whitespace- or comma-separated numbers, ``header_lines`` lines skipped first; a non-zero
value means the sensor detected in that period. Row k (from 0) is at event time ``k·period`` s.
Sensor table: a CSV whose header names ``column`` (1-based matrix column) and/or ``id``, and
``x``, ``y`` — optionally with a unit suffix (``x_mm``, ``y_cm``, ``x_m``, ``x_ft``); a ``units``
option overrides the suffix. Positions are converted to metres.
"""

from __future__ import annotations

import csv
import math
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bintrack.formats import Event, FormatError
from bintrack.deployment_model import check_sensor_id

METRES_PER = {"mm": 0.001, "cm": 0.01, "m": 1.0, "km": 1000.0, "in": 0.0254, "ft": 0.3048}
"""metres in one of each length unit the importer reads"""


def unit_factor(unit: str, source: str) -> float:
    """Metres in one ``unit``; ``FormatError`` naming ``source`` for an unknown unit."""
    factor = METRES_PER.get(unit.strip().lower())
    if factor is None:
        raise FormatError(source, None, "units", f"unknown length unit {unit!r} (known: {', '.join(METRES_PER)})")
    return factor


def parse_columns(text: str) -> list[int]:
    """1-based column numbers from ``"1-43"``, ``"1,3,5-9"``; ValueError (one line) when malformed."""
    out: list[int] = []
    for part in text.split(","):
        part = part.strip()
        m = re.fullmatch(r"(\d+)(?:-(\d+))?", part)
        if not m:
            raise ValueError(f"columns: {part!r} is not N or N-M (1-based)")
        a, b = int(m.group(1)), int(m.group(2) or m.group(1))
        if a < 1 or b < a:
            raise ValueError(f"columns: {part!r} needs 1 <= N <= M")
        out.extend(range(a, b + 1))
    if len(set(out)) != len(out):
        raise ValueError("columns: a column is listed twice")
    return out


@dataclass(frozen=True)
class SensorRow:
    """One sensor of the table: its id, its 1-based matrix column, and its position in metres."""

    id: str
    column: int
    x: float
    y: float


def _axis_field(header: list[str], axis: str) -> tuple[str, str | None]:
    for name in header:
        m = re.fullmatch(rf"{axis}(?:_([a-z]+))?", name.strip().lower())
        if m:
            return name, m.group(1)
    raise ValueError(f"no {axis} column")


def read_sensor_table(path: Path | str, units: str | None = None, columns: list[int] | None = None) -> list[SensorRow]:
    """The sensors of the table at ``path``, positions in metres (``units``: the table's unit,
    default the field names' suffix). With a ``column`` field, ``columns`` (1-based) selects the
    sensors that read those columns; without one, the rows read ``columns`` in order (default
    1, 2, …). Without an ``id`` field a sensor's id is its column number."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise FormatError(path, None, "file", getattr(exc, "strerror", None) or str(exc)) from None
    reader = csv.DictReader(text.splitlines())
    header = reader.fieldnames or []
    try:
        xf, xunit = _axis_field(header, "x")
        yf, yunit = _axis_field(header, "y")
    except ValueError as exc:
        raise FormatError(path, 1, "header", f"{exc} (expected x and y, or x_mm and y_mm, ...)") from None
    lower = {h.strip().lower(): h for h in header}
    unit = units or xunit or yunit
    if unit is None:
        raise FormatError(path, 1, "header", "positions have no unit: name the fields x_mm/y_mm (or _cm, _m, _ft) or give --sensor-units")
    if units is None and xunit != yunit:
        raise FormatError(path, 1, "header", f"x is in {xunit} but y in {yunit}")
    scale = unit_factor(unit, str(path))
    rows: list[SensorRow] = []
    for k, row in enumerate(reader):
        line = k + 2
        values = {}
        for field in (xf, yf):
            try:
                values[field] = float(row[field])
            except (TypeError, ValueError):
                raise FormatError(path, line, field, f"not a number: {row.get(field)!r}") from None
            if not math.isfinite(values[field]):
                raise FormatError(path, line, field, f"not a finite number: {row.get(field)!r}")
        if "column" in lower:
            try:
                column = int(row[lower["column"]])
            except (TypeError, ValueError):
                raise FormatError(path, line, "column", f"not a whole number: {row.get(lower['column'])!r}") from None
            if column < 1:
                raise FormatError(path, line, "column", f"columns count from 1, got {column}")
        elif columns is not None:
            if k >= len(columns):
                raise FormatError(path, line, "column", f"more sensors than the {len(columns)} columns given")
            column = columns[k]
        else:
            column = k + 1
        sid = (row.get(lower["id"]) or "").strip() if "id" in lower else str(column)
        try:
            check_sensor_id(sid)
        except ValueError as exc:
            raise FormatError(path, line, "id", str(exc)) from None
        rows.append(SensorRow(sid, column, values[xf] * scale, values[yf] * scale))
    if not rows:
        raise FormatError(path, None, "file", "no sensors")
    if columns is not None and "column" in lower:
        missing = sorted(set(columns) - {r.column for r in rows})
        if missing:
            raise FormatError(path, None, "column", f"no sensor reads column {missing[0]}")
        rows = [r for r in rows if r.column in set(columns)]
    elif columns is not None and len(rows) != len(columns):
        raise FormatError(path, None, "file", f"{len(rows)} sensors for the {len(columns)} columns given")
    for field, key in (("id", lambda r: r.id), ("column", lambda r: r.column)):
        seen = set()
        for k, r in enumerate(rows):
            if key(r) in seen:
                raise FormatError(path, k + 2, field, f"{key(r)!r} appears twice")
            seen.add(key(r))
    return rows


def read_sample_matrix(path: Path | str, header_lines: int = 0) -> np.ndarray:
    """The matrix at ``path`` as a float array (rows × columns), ``header_lines`` lines skipped;
    separators are whitespace or commas; every row must have the same number of fields."""
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise FormatError(path, None, "file", getattr(exc, "strerror", None) or str(exc)) from None
    rows: list[list[float]] = []
    width = None
    for k, text in enumerate(lines[header_lines:], start=header_lines + 1):
        fields = text.replace(",", " ").split()
        if not fields:
            continue
        try:
            values = [float(f) for f in fields]
        except ValueError:
            bad = next(f for f in fields if not _is_number(f))
            raise FormatError(path, k, "sample", f"not a number: {bad!r} (is it a header line? see --header-lines)") from None
        if width is None:
            width = len(values)
        elif len(values) != width:
            raise FormatError(path, k, "sample", f"{len(values)} fields where the first row has {width}")
        rows.append(values)
    if not rows:
        raise FormatError(path, None, "file", "no samples")
    matrix = np.array(rows)
    if not np.isfinite(matrix).all():
        raise FormatError(path, None, "sample", "a sample is not a finite number")
    return matrix


def _is_number(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


def matrix_events(matrix: np.ndarray, sensors: list[SensorRow], period: float, path: Path | str = "matrix") -> Iterator[Event]:
    """DESIGN §6 disk events (transitions only) of the sensors' columns: row k at ``k·period`` s,
    a non-zero sample is 1. Each sensor starts absent (0), so a first row of 0 writes nothing."""
    width = matrix.shape[1]
    for s in sensors:
        if s.column > width:
            raise FormatError(path, None, "column", f"sensor {s.id} reads column {s.column} but the matrix has {width}")
    status = (matrix[:, [s.column - 1 for s in sensors]] != 0).astype(int)
    previous = np.zeros(len(sensors), dtype=int)
    for k, row in enumerate(status):
        t = round(k * period, 9)
        for i in np.flatnonzero(row != previous):
            yield Event(t, sensors[i].id, int(row[i]))
        previous = row
