"""``python -m bintrack.services.health SERVICE``: is some instance of SERVICE alive on the bus?

Exits 0, printing the live instances, when at least one instance holds its liveliness token
``bintrack/<net>/alive/SERVICE/<id>``; otherwise exits 1 with a one-line reason (no router
reachable, no such token, bad configuration). It is the docker-compose healthcheck, so it
declares nothing and gives up quickly: ``--wait`` (reaching the router) defaults to 5 s here.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import sys

from bintrack.live.session_options import add_bus_arguments
from bintrack.live.network_client import BintrackClient
from bintrack.keys import Keys

CONNECT_WAIT = 5.0


def service_name(value: str) -> str:
    """``value`` if it can be a service name in a key expression (argparse type)."""
    try:
        Keys().alive(value, "*")
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m bintrack.services.health",
        description="Exit 0 if some instance of SERVICE holds its liveliness token "
                    "bintrack/<net>/alive/SERVICE/*, else 1 with a one-line reason.")
    parser.add_argument("service", type=service_name, metavar="SERVICE",
                        help="service name, e.g. sensor_agent, basestation, recorder")
    parser.add_argument("--timeout", type=float, default=2.0, metavar="S",
                        help="how long to wait for liveliness replies, s (default: %(default)s)")
    add_bus_arguments(parser)
    parser.set_defaults(wait=CONNECT_WAIT)
    return parser


async def probe(args: argparse.Namespace) -> tuple[int, str]:
    """(exit status, one line) for the liveliness of ``args.service``."""
    try:
        async with BintrackClient.from_args(args) as client:
            instances = await client.alive(args.service, timeout=args.timeout)
    except (ValueError, ConnectionError) as exc:
        return 1, f"health: {args.service}: {exc}"
    if not instances:
        where = client.keys.alive(args.service, "*")
        return 1, f"health: {args.service}: no live instance (no liveliness token on {where})"
    names = ", ".join(instance for _, instance in instances)
    return 0, f"health: {args.service}: alive ({len(instances)} instance{'s' * (len(instances) != 1)}: {names})"


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    # The reason is the one line; silence the session's "waiting for the router" warnings.
    logging.getLogger("bintrack").setLevel(logging.ERROR)
    status, line = asyncio.run(probe(args))
    print(line, file=sys.stdout if status == 0 else sys.stderr)
    return status


if __name__ == "__main__":
    sys.exit(main())
