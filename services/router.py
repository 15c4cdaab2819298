"""Zenoh router: one node of the router mesh between sites (DESIGN §9, several machines).

``python -m bintrack.services.router -l tcp/ADDR:PORT [-e PEER …]`` runs a zenoh-python session
in router mode (the ``zenohd`` binary is not on the package registries; in Docker the official
``eclipse/zenoh`` image plays this part). It listens on ``-l``, connects to the other routers of
the mesh with ``-e`` (Zenoh retries a router that is not up yet, and again after it went), and
logs each router, peer or client that connects or leaves. Ends cleanly on SIGTERM or SIGINT.
With ``RUST_LOG`` set, Zenoh's own log goes to stdout: ``RUST_LOG=zenoh::net::routing::interceptor::
access_control=trace`` shows each message the access control denies (and each it lets pass).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading

import zenoh

from bintrack.keys import Keys
from bintrack.live.parent_watch import PARENT_ENV
from bintrack.live.service import configure_logging, log
from bintrack.live.session_options import no_scouting_wait, zenoh_config


def mesh_config(args: argparse.Namespace) -> zenoh.Config:
    """The router's config: the options as every service takes them, mode router, no scouting
    (the mesh is what ``-e`` says), and connections retried for ever."""
    args.mode = "router"
    config = zenoh_config(args)
    if not (args.config or any(c.startswith("scouting/gossip") for c in args.cfg)):
        config.insert_json5("scouting/gossip/enabled", "false")
        if not any(c.startswith("scouting/delay") for c in args.cfg):
            no_scouting_wait(config)
    if args.connect:
        # a router of the mesh that is down (or not up yet) is retried, not given up on
        config.insert_json5("connect/timeout_ms", json.dumps({"router": -1, "peer": -1, "client": 0}))
        config.insert_json5("connect/exit_on_failure", json.dumps({"router": False, "peer": False, "client": True}))
    return config


def pinned_tokens(spec: str) -> tuple[str, dict[str, list[str]]]:
    """``NET:SERVICE[=ID],…`` (an instance id defaults to its service's name, as in the compose
    files) as (net, the liveliness token keys of each role); ValueError if malformed."""
    net, colon, instances = spec.partition(":")
    if not colon or not instances:
        raise ValueError(f"--pin-tokens takes NET:SERVICE[=ID],…, got {spec!r}")
    from bintrack.live.secure_profile import role_of  # the secure profile only: its imports take 0.8 s

    keys = Keys(net)
    tokens: dict[str, list[str]] = {}
    for item in instances.split(","):
        service, _, instance = item.partition("=")
        tokens.setdefault(role_of(service), []).append(keys.alive(service, instance or service))
    return net, tokens


def describe(transport) -> str:
    return f"{str(transport.whatami).lower()} {str(transport.zid)[:8]}"


def run(args: argparse.Namespace) -> int:
    if not args.listen:
        log.error("router: give at least one -l/--listen endpoint")
        return 2
    try:
        config = mesh_config(args)
        if args.pin_tokens:
            if not config.get_json("access_control/enabled") == "true":
                raise ValueError("--pin-tokens needs a config with access control (the secure profile's router.json5)")
            from bintrack.live.secure_profile import pin_tokens

            pin_tokens(config, pinned_tokens(args.pin_tokens)[1])
    except ValueError as exc:
        log.error("router: %s", exc)
        return 2
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda signum, frame: stop.set())
    try:
        session = zenoh.open(config)
    except zenoh.ZError as exc:
        log.error("router: cannot start on %s: %s", ", ".join(args.listen), str(exc).split(" at ")[0])
        return 1

    remote: dict[str, str] = {}  # a peer's zid → the address its link comes from or goes to

    def on_link(event) -> None:  # a Zenoh thread
        if event.kind == zenoh.SampleKind.PUT:
            remote[str(event.link.zid)] = str(event.link.dst)

    def on_event(event) -> None:  # a Zenoh thread: logging only
        where = remote.get(str(event.transport.zid))
        at = f" ({where})" if where else ""
        if event.kind == zenoh.SampleKind.PUT:
            log.info("router %s: %s connected%s", args.name, describe(event.transport), at)
        else:
            log.warning("router %s: %s left%s", args.name, describe(event.transport), at)

    links = session.info.declare_link_events_listener(on_link, history=True)
    listener = session.info.declare_transport_events_listener(on_event, history=True)
    log.info("router %s (%s): listening on %s%s", args.name, str(session.info.zid())[:8], ", ".join(args.listen),
             f", meshed with {', '.join(args.connect)}" if args.connect else "")
    parent = os.environ.get(PARENT_ENV)  # under `bintrack up`: end with it
    try:
        while not stop.wait(0.5):
            if parent and os.getppid() != int(parent):
                log.warning("router %s: its supervisor (pid %s) is gone; stopping", args.name, parent)
                break
    finally:
        listener.undeclare()
        links.undeclare()
        session.close()
        log.info("router %s: stopped", args.name)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m bintrack.services.router", description=__doc__.splitlines()[0])
    group = parser.add_argument_group("Zenoh session")
    group.add_argument("-l", "--listen", action="append", default=[], metavar="ENDPOINT",
                       help="endpoint to listen on, repeatable (required)")
    group.add_argument("-e", "--connect", action="append", default=[], metavar="ENDPOINT",
                       help="another router of the mesh to connect to, repeatable")
    group.add_argument("-c", "--config", metavar="FILE", help="Zenoh configuration file (JSON5); default: $ZENOH_CONFIG")
    group.add_argument("--cfg", action="append", default=[], metavar="KEY:VALUE",
                       help="set a configuration key to a JSON5 value")
    parser.add_argument("--pin-tokens", metavar="NET:SERVICE[=ID],…",
                        help="with the secure profile: each role may declare the liveliness tokens of these instances "
                        "only (ID defaults to the service's name), so that no holder of a role's certificate can "
                        "pose as another instance of it")
    parser.add_argument("--name", default="router", help="name in the log lines (default: %(default)s)")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    configure_logging(args.verbose)
    zenoh.try_init_log_from_env()  # RUST_LOG: Zenoh's own log on stdout (access control's denials at trace)
    return run(args)


if __name__ == "__main__":
    sys.exit(main())
