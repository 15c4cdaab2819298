"""argparse option types shared by the subcommands: a bad value is a one-line usage error."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable


def non_negative_float(text: str) -> float:
    """A finite number ≥ 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"must be a number >= 0, got {text!r}")
    return value


def positive_float(text: str) -> float:
    """A finite number > 0."""
    value = non_negative_float(text)
    if value == 0:
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
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
