"""How a bintrack program reaches the bus: the Zenoh examples' options, the configurations they
make (a client of the router by default, routers on loopback) and a session opened with
retries while the router is not up yet."""

from __future__ import annotations

import argparse
import json
import logging
import os
import threading
import time
from collections.abc import Callable, Iterable

import zenoh

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
DEFAULT_MAX_PAYLOAD = 64 * 1024  # bytes; no bintrack message comes near it
STATE_DIR_OPTION = "--state-dir"
STACK_OPTION = "--stack"

log = logging.getLogger("bintrack")


def add_bus_arguments(parser: argparse.ArgumentParser, *, net_default: str | None = "default",
                      checkpoint: bool = True) -> None:
    """The Zenoh examples' options, plus the network name and how long to wait for the router
    (and, if ``checkpoint``, the state folder of a service)."""
    group = parser.add_argument_group("Zenoh session")
    group.add_argument("-m", "--mode", choices=("peer", "client", "router"),
                       help="Zenoh mode (default: client of the router, or as the config file says)")
    group.add_argument("-e", "--connect", action="append", default=[], metavar="ENDPOINT",
                       help=f"endpoint to connect to, repeatable (default: {DEFAULT_ENDPOINT})")
    group.add_argument("-l", "--listen", action="append", default=[], metavar="ENDPOINT",
                       help="endpoint to listen on, repeatable")
    group.add_argument("-c", "--config", metavar="FILE",
                       help="Zenoh configuration file (JSON5); default: $ZENOH_CONFIG if set")
    group.add_argument("--cfg", action="append", default=[], metavar="KEY:VALUE",
                       help="set a configuration key to a JSON5 value, e.g. --cfg 'scouting/multicast/enabled:false'")
    group.add_argument("--net", default=net_default, metavar="NAME",
                       help="network (deployment) name, the <net> of bintrack/<net>/…"
                       + (f" (default: {net_default})" if net_default else ""))
    group.add_argument("--wait", type=float, default=60.0, metavar="S",
                       help="how long to keep retrying to reach the router, s (default: %(default)s)")
    group.add_argument("--max-payload", type=int, default=DEFAULT_MAX_PAYLOAD, metavar="BYTES",
                       help="refuse a sample larger than this before reading it (default: %(default)s)")
    if checkpoint:
        group.add_argument(STATE_DIR_OPTION, metavar="DIR",
                           help="keep a checkpoint of this instance (named by --id) in DIR and resume from it "
                           "after a restart (default: none)")
        group.add_argument(STACK_OPTION, metavar="ID",
                           help="the run this instance belongs to (`up` gives its own): a liveliness token of an "
                           "instance whose id does not start with ID- is another's, logged once and ignored "
                           "(default: every token counts)")


def zenoh_config(args: argparse.Namespace) -> zenoh.Config:
    """A Zenoh config from the options: file (-c, else $ZENOH_CONFIG), then --cfg, -m, -e, -l.

    With no file, the default is a client of the router at 127.0.0.1:7447 with multicast
    scouting off, so nothing leaves loopback unless asked to.
    """
    path = args.config or os.environ.get("ZENOH_CONFIG")
    try:
        if path:
            config = zenoh.Config.from_file(path)
        else:
            config = zenoh.Config()
            config.insert_json5("scouting/multicast/enabled", "false")
        for item in args.cfg:
            key, sep, value = item.partition(":")
            if not sep or not key:
                raise ValueError(f"--cfg takes KEY:VALUE, got {item!r}")
            config.insert_json5(key, value)
        mode = args.mode or (None if path else "client")
        if mode:
            config.insert_json5("mode", json.dumps(mode))
        connect = args.connect or ([] if path or mode != "client" else [DEFAULT_ENDPOINT])
        if connect:
            config.insert_json5("connect/endpoints", json.dumps(connect))
        if args.listen:
            config.insert_json5("listen/endpoints", json.dumps(args.listen))
    except zenoh.ZError as exc:  # a missing or bad file, an unknown key, a value that is not JSON5
        raise ValueError(f"bad Zenoh configuration: {exc}") from None
    return config


def client_config(endpoints: Iterable[str]) -> zenoh.Config:
    """A client of the router(s) at ``endpoints``, no multicast scouting (as services default to)."""
    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", json.dumps(list(endpoints)))
    config.insert_json5("scouting/multicast/enabled", "false")
    return config


def router_config(listen: Iterable[str] = (DEFAULT_ENDPOINT,)) -> zenoh.Config:
    """An in-process Zenoh router listening on ``listen`` (loopback by default), no scouting."""
    config = zenoh.Config()
    config.insert_json5("mode", '"router"')
    config.insert_json5("listen/endpoints", json.dumps(list(listen)))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("scouting/gossip/enabled", "false")
    return no_scouting_wait(config)


def no_scouting_wait(config: zenoh.Config) -> zenoh.Config:
    """``config`` opening at once: a router (or peer) otherwise waits ``scouting/delay`` (0.5 s)
    for peers to scout before ``zenoh.open`` returns, which without scouting finds none."""
    config.insert_json5("scouting/delay", "0")
    return config


def open_session(config: zenoh.Config, wait: float = 60.0, who: str = "bintrack",
                 stop: threading.Event | None = None, unreachable: Callable[[], None] | None = None) -> zenoh.Session:
    """Open a session, retrying while the router is not up yet, with a clear message;
    ``unreachable()`` is called once, when the first attempt failed, before waiting.

    Raises ``ConnectionError`` after ``wait`` seconds (or when ``stop`` is set).
    """
    deadline = time.monotonic() + wait
    attempt = 0
    while True:
        attempt += 1
        try:
            return zenoh.open(config)
        except zenoh.ZError as exc:
            reason = str(exc).split(" at ")[0]
            if attempt == 1 and unreachable is not None:
                unreachable()
            if time.monotonic() >= deadline or (stop is not None and stop.is_set()):
                raise ConnectionError(f"{who}: no Zenoh router reachable after {attempt} attempts: {reason}") from None
            if attempt == 1 or attempt % 10 == 0:
                log.warning("%s: waiting for the Zenoh router (%s); retrying", who, reason)
            if stop is not None:
                stop.wait(0.5)
            else:
                time.sleep(0.5)

