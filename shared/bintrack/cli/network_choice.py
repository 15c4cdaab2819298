"""Which network a live command (``watch``, ``view``, ``record``) follows: ``--net``, else the
one network alive on the bus, said in one line."""

from __future__ import annotations

import argparse
import sys

from bintrack.errors import CommandError
from bintrack.live.session_options import open_session, zenoh_config
from bintrack.live.network_client import the_network


def no_router(args: argparse.Namespace) -> str:
    """The one line for "no router answered": where we looked, and what to do."""
    where = ", ".join(args.connect) if args.connect else "the default endpoint tcp/127.0.0.1:7447"
    return (f"no Zenoh router reachable at {where} within {args.wait:g} s; start a stack with "
            "`bintrack up DIR`, or give the router with -e ENDPOINT")


def network_of(args: argparse.Namespace, command: str) -> str:
    """``args.net`` if given; else the one network alive on the bus, said on stderr. Raises
    CommandError (one line) when no router answers, or none or several networks are alive."""
    if args.net:
        return args.net
    try:
        session = open_session(zenoh_config(args), args.wait, f"bintrack {command}")
    except ConnectionError:
        raise CommandError(no_router(args)) from None
    except ValueError as exc:
        raise CommandError(str(exc)) from None
    try:
        net = the_network(session)
    except ValueError as exc:
        raise CommandError(str(exc)) from None
    finally:
        session.close()
    print(f"bintrack {command}: network {net} (the one alive on the bus)", file=sys.stderr, flush=True)
    return net
