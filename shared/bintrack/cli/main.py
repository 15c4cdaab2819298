"""``bintrack``: the command line of DESIGN §7.

Each subcommand lives in its own module exposing ``add_arguments(parser)`` and
``run(args) -> int``. Bad input (a malformed file, a bad option) prints one line to stderr
and exits with status 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from bintrack import __version__
from bintrack.errors import CommandError, TrackerConfigError
from bintrack.formats import FormatError

# subcommand -> (module implementing it, one-line help); only the chosen module is imported
SUBCOMMANDS = {
    "simulate": ("bintrack.cli.simulate_command", "write a simulated dataset for a named paper scenario"),
    "track": ("bintrack.cli.track_command", "run a tracker offline over a dataset folder and write tracks.csv"),
    "import": ("bintrack.cli.import_command", "a sample matrix, sensor table and CVML truth as a dataset"),
    "calibrate": ("bintrack.cli.calibrate_command", "fit each sensor's footprint, pd, pfa, hold to a recording"),
    "eval": ("bintrack.cli.eval_command", "score tracks.csv or objects.csv against the dataset's truth.csv"),
    "schema": ("bintrack.cli.schema_command", "print the JSON Schema of every bus message"),
    "up": ("bintrack.cli.up_command", "the whole stack on this machine: router, services, and the replay of DIR"),
    "demo": ("bintrack.cli.demo_command", "the README's main job: track the shipped 3-person dataset, print and plot"),
    "replay": ("bintrack.cli.replay_command", "play a dataset folder or a recording onto the bus, flow-controlled"),
    "record": ("bintrack.cli.record_command", "record bintrack/<net>/** into an MCAP recording until stopped"),
    "export": ("bintrack.cli.export_command", "write a recording's tracks, estimates, objects or velocities as CSV"),
    "watch": ("bintrack.cli.watch_command", "print live tracks, estimates or transitions of a network until Ctrl-C"),
    "view": ("bintrack.cli.view_command", "the map in the browser: the live network, or a recording with a time slider"),
    "certs": ("bintrack.cli.certs_command", "make a CA and a certificate + key per role for the secure profile"),
    "bounds": ("bintrack.cli.bounds_command", "print the analytic accuracy limits of the arc tracker (paper 001 §4)"),
}


class _CommandListFormatter(argparse.HelpFormatter):
    """argparse's formatter, but a command name as long as "calibrate" keeps its help beside it
    (argparse measures the commands without their extra indent, and wraps the longest)."""

    def add_argument(self, action):
        super().add_argument(action)
        if isinstance(action, argparse._SubParsersAction):
            longest = max((len(name) for name in action.choices), default=0)
            self._action_max_length = max(self._action_max_length,
                                          longest + self._current_indent + 2 * self._indent_increment)


def build_parser(chosen: str | None = None) -> argparse.ArgumentParser:
    """The parser; only subcommand ``chosen`` gets its options (and its module imported)."""
    parser = argparse.ArgumentParser(
        prog="bintrack",
        description="Track moving targets with networks of binary sensors.",
        formatter_class=_CommandListFormatter,
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
    if not argv:   # `bintrack` alone: what it can do
        build_parser().print_help()
        return 0
    args = build_parser(chosen).parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except (FormatError, CommandError, TrackerConfigError) as exc:
        print(f"bintrack {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        return 0
    except ModuleNotFoundError as exc:
        package = (exc.name or "").split(".")[0]
        if not package or package == "bintrack":
            raise
        # e.g. the container image leaves out matplotlib and motmetrics, which no service uses
        print(f"bintrack {args.command}: error: this needs the Python package {package}, which this "
              f"installation leaves out (pip install {package})", file=sys.stderr)
        return 2
    except OSError as exc:
        if exc.filename is None:
            raise
        # a path the checks before the work did not catch: still one line, not a traceback
        print(f"bintrack {args.command}: error: {exc.filename}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"bintrack {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
