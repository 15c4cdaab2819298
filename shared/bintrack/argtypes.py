"""argparse option types shared by the subcommands: a bad value is a one-line usage error."""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections.abc import Callable
from pathlib import Path

from bintrack.errors import CommandError


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None


def non_negative_float(text: str) -> float:
    """A finite number ≥ 0."""
    value = _number(text)
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"must be a number >= 0, got {text!r}")
    return value


def positive_float(text: str) -> float:
    """A finite number > 0."""
    value = _number(text)
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text!r}")
    return value


def int_at_least(minimum: int) -> Callable[[str], int]:
    """An option type: a whole number ≥ ``minimum``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be at least {minimum}, got {text!r}")
        return value

    return parse


def size_bytes(text: str) -> int:
    """``123``, ``64K``, ``100M`` or ``2G`` (powers of 1024) as a positive number of bytes (argparse type)."""
    units = {"K": 1024, "M": 1024**2, "G": 1024**3}
    try:
        value = int(float(text[:-1]) * units[text[-1].upper()]) if text[-1:].upper() in units else int(text)
    except ValueError:
        value = 0
    if value <= 0:
        raise argparse.ArgumentTypeError(f"not a positive size in bytes: {text!r} (e.g. 100M)")
    return value


def port_number(text: str) -> int:
    """A TCP port, 0..65535 (0: any free one)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a port number: {text!r}") from None
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"a port is 0..65535, got {value}")
    return value


def output_folder(path: Path) -> Path:
    """Create folder ``path`` (and its parents) for a command's output; CommandError (one line)
    if it cannot be: a file in the way, no permission."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise CommandError(f"{path}: not a folder (a file is in the way)") from None
    except OSError as exc:
        raise CommandError(f"cannot create the folder {path}: {exc.strerror or exc}") from None
    probe = path / f".bintrack-write-check-{os.getpid()}"
    try:
        probe.touch()
        probe.unlink()
    except OSError as exc:
        raise CommandError(f"cannot write into {path}: {exc.strerror or exc}") from None
    return path


def output_file(path: Path | str, *, what: str = "") -> Path:
    """Check that file ``path`` can be written (by opening it) before any work is done;
    CommandError, one line "cannot write [what] PATH: why", if it is a folder, its folder is
    missing or not a folder, or it cannot be written. ``what`` names the file, e.g. "plot"."""
    path = Path(path)
    name = f"{what} {path}" if what else str(path)
    if path.is_dir():
        raise CommandError(f"cannot write {name}: it is a folder; give a file name")
    if not path.parent.is_dir():
        why = "no such folder" if not path.parent.exists() else "not a folder"
        raise CommandError(f"cannot write {name}: {path.parent}: {why}")
    existed = path.exists()
    try:
        with open(path, "ab"):
            pass
    except OSError as exc:
        raise CommandError(f"cannot write {name}: {exc.strerror or exc}") from None
    if not existed:
        path.unlink()
    return path


_warned: set[str] = set()


def add_alias(parser: argparse.ArgumentParser, old: str, new: str, dest: str, *, flag_value: object = None,
              **kwargs) -> None:
    """``old``, an earlier name of option ``new``: still accepted (into ``dest``), hidden from
    ``--help``, and its first use in this process prints one warning line to stderr.
    ``flag_value``: the value a flag without argument stores (e.g. False for ``--no-view``)."""

    class Alias(argparse.Action):
        def __call__(self, parser, namespace, values, option_string=None):
            if old not in _warned:
                _warned.add(old)
                print(f"{parser.prog}: warning: {old} is now {new}", file=sys.stderr)
            setattr(namespace, self.dest, flag_value if self.nargs == 0 else values)

    parser.add_argument(old, dest=dest, action=Alias, nargs=0 if flag_value is not None else None,
                        default=argparse.SUPPRESS, help=argparse.SUPPRESS, **kwargs)


def area_type(text: str) -> tuple[float, float, float, float]:
    """XMIN,YMIN,XMAX,YMAX: a rectangle with XMIN < XMAX and YMIN < YMAX."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"not four numbers xmin,ymin,xmax,ymax: {text!r}") from None
    if len(values) != 4 or not (values[0] < values[2] and values[1] < values[3]):
        raise argparse.ArgumentTypeError(f"needs xmin,ymin,xmax,ymax with xmin < xmax and ymin < ymax, got {text!r}")
    return values
