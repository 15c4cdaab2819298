"""``bintrack``: the command line of DESIGN §7.

Each subcommand lives in its own module exposing ``add_arguments(parser)`` and
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

# subcommand -> (module implementing it, one-line help); only the chosen module is imported
SUBCOMMANDS = {
    "simulate": ("bintrack.sim.command", "write a simulated dataset for a named paper scenario"),
    "track": ("bintrack.track_command", "run a tracker offline over a dataset folder and write tracks.csv"),
    "eval": ("bintrack.evaluation", "score tracks.csv or objects.csv against the dataset's truth.csv"),
    "schema": ("bintrack.schema_command", "print the JSON Schema of every bus message"),
    "up": ("bintrack.up", "the whole stack on this machine: router, services, and the replay of DIR"),
    "demo": ("bintrack.demo", "the README's main job: track the shipped 3-person dataset, print and plot"),
    "replay": ("bintrack.replay_command", "play a dataset folder or a recording onto the bus, flow-controlled"),
    "record": ("bintrack.record_command", "record bintrack/<net>/** into an MCAP recording until stopped"),
    "export": ("bintrack.export_command", "write a recording's tracks, estimates, objects or velocities as CSV"),
    "watch": ("bintrack.watch_command", "print live tracks, estimates or transitions of a network until Ctrl-C"),
    "view": ("bintrack.view_command", "the map in the browser: the live network, or a recording with a time slider"),
    "bounds": ("bintrack.bounds_command", "print the analytic accuracy limits of the arc tracker (paper 001 §4)"),
}


def build_parser(chosen: str | None = None) -> argparse.ArgumentParser:
    """The parser; only subcommand ``chosen`` gets its options (and its module imported)."""
    parser = argparse.ArgumentParser(
        prog="bintrack",
        description="Track moving targets with networks of binary sensors.",
    )
    parser.add_argument("--version", action="version", version=f"bintrack {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, (module_name, help_text) in SUBCOMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        if name == chosen:
            module = importlib.import_module(module_name)
            module.add_arguments(p)
            p.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    chosen = next((a for a in argv if not a.startswith("-")), None)
    args = build_parser(chosen).parse_args(argv)
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
