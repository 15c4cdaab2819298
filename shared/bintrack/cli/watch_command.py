"""``bintrack watch``: print live messages of a network, one line each, until Ctrl-C.

``--what tracks`` (default) prints each TrackSet, ``estimates`` each LocalEstimate and
``transitions`` each Transition. Positions are in deployment units, velocities in units/s,
times in s of event time. Payloads that do not decode are skipped, reported once per sender
on stderr, and counted; the counts are reported at the end. Without ``--net`` it watches the
one network alive on the bus, and lists them if there are several.
"""

from __future__ import annotations

import argparse
import asyncio
import signal
import sys

from bintrack.cli.network_choice import no_router
from bintrack.live.session_options import add_bus_arguments
from bintrack.live.network_client import BintrackClient
from bintrack.bus_payloads import LocalEstimate, TrackSet, Transition

WHAT = ("tracks", "estimates", "transitions")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--what", choices=WHAT, default="tracks",
                        help="which messages to print (default: %(default)s)")
    parser.add_argument("--region", metavar="NAME",
                        help="with --what tracks: one region's base station's tracks (region/NAME/tracks)")
    add_bus_arguments(parser, net_default=None, checkpoint=False)
    parser.set_defaults(wait=10.0)  # a newcomer without a stack hears so in 10 s, not 60
    parser.epilog = "Without --net, the one network alive on the bus (the alive ones are listed if several)."


def _num(value: float | None, digits: int = 2) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def format_trackset(message: TrackSet) -> str:
    """``t=12.500 tracker=mcmcda tracks=2 | #0 (1.00, 2.00) v=(0.50, -0.10) | #3 (…) v=(-, -)``."""
    parts = [f"t={message.t:.3f} tracker={message.tracker} tracks={len(message.tracks)}"]
    parts += [f"#{k.track} ({_num(k.x)}, {_num(k.y)}) v=({_num(k.vx)}, {_num(k.vy)})"
              + (f" {k.region}" if k.region else "") + (" stale" if k.stale else "") for k in message.tracks]
    return " | ".join(parts)


def format_estimate(message: LocalEstimate) -> str:
    """``t=3.250 node=n17 tracker=arc x=10.00 y=4.00 v=(1.00, 0.00)``."""
    return (f"t={message.t:.3f} node={message.node} tracker={message.tracker} "
            f"x={_num(message.x)} y={_num(message.y)} v=({_num(message.vx)}, {_num(message.vy)})")


def format_transition(message: Transition) -> str:
    """``t=3.250 sensor=n17 0->1 seq=4``."""
    return f"t={message.t:.3f} sensor={message.sensor} {message.previous}->{message.value} seq={message.seq}"


async def watch(args: argparse.Namespace) -> int:
    """Print until SIGINT/SIGTERM; 0 on a clean stop, 1 if no router was reachable."""
    loop = asyncio.get_running_loop()
    if getattr(args, "region", None) and args.what != "tracks":
        print(f"bintrack watch: --region goes with --what tracks, not {args.what}", file=sys.stderr)
        return 2
    try:
        client = await BintrackClient.from_args(args).open()
    except ConnectionError:
        print(f"bintrack watch: {no_router(args)}", file=sys.stderr)
        return 1
    except ValueError as exc:
        print(f"bintrack watch: {exc}", file=sys.stderr)
        return 1
    try:
        subscription, fmt = {
            "tracks": (client.tracks, format_trackset),
            "estimates": (client.estimates, format_estimate),
            "transitions": (client.transitions, format_transition),
        }[args.what]
        messages = subscription(region=args.region) if getattr(args, "region", None) else subscription()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, messages.close)
        print(f"bintrack watch: {args.what} on {messages.key_expr} (Ctrl-C to stop)", file=sys.stderr, flush=True)
        async for message in messages:
            print(fmt(message), flush=True)
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)
        await client.close()  # logs the bad and dropped counts, if any, to stderr
    return 0


def run(args: argparse.Namespace) -> int:
    return asyncio.run(watch(args))
