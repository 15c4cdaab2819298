"""``bintrack``: the command line of DESIGN §7.

Each subcommand lives in its own module exposing ``HELP``, ``add_arguments(parser)`` and
``run(args) -> int``. Bad input (a malformed file, a bad option) prints one line to stderr
and exits with status 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from . import __version__
from .errors import CommandError
from .formats import FormatError

# subcommand -> module implementing it
SUBCOMMANDS = {
    "simulate": "bintrack.sim.command",
    "track": "bintrack.track_command",
    "eval": "bintrack.evaluation",
    "schema": "bintrack.schema_command",
    "demo": "bintrack.demo",
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bintrack",
        description="Track moving targets with networks of binary sensors.",
    )
    parser.add_argument("--version", action="version", version=f"bintrack {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, module_name in SUBCOMMANDS.items():
        module = importlib.import_module(module_name)
        p = sub.add_parser(name, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except (FormatError, CommandError) as exc:
        print(f"bintrack {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"bintrack {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0


if __name__ == "__main__":
    sys.exit(main())
