"""``bintrack schema``: print the JSON Schema of every bus message."""

from __future__ import annotations

import argparse

from bintrack.argtypes import output_file
from bintrack.message_schema import json_schema_text


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", help="write to this file instead of standard output")


def run(args: argparse.Namespace) -> int:
    text = json_schema_text() + "\n"
    if args.out:
        output_file(args.out)
        with open(args.out, "w", encoding="utf-8") as handle:
            handle.write(text)
    else:
        print(text, end="")
    return 0
