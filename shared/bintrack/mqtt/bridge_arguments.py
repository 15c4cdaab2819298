"""The options of the MQTT bridge service (``python -m bintrack.services.mqtt_bridge``)."""

from __future__ import annotations

import argparse

from bintrack.argtypes import int_at_least, non_negative_float, positive_float
from bintrack.live.session_options import add_bus_arguments


def build_parser() -> argparse.ArgumentParser:
    """The bridge's options and the Zenoh session's."""
    parser = argparse.ArgumentParser(prog="python -m bintrack.services.mqtt_bridge",
                                     description="binary sensors on an MQTT broker as the stack's source")
    add_arguments(parser)
    add_bus_arguments(parser, net_default=None)
    return parser


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Everything but the Zenoh session's options."""
    p.add_argument("broker", metavar="mqtt://HOST:PORT", help="the broker (mqtts:// for TLS)")
    p.add_argument("--sensor-table", required=True, metavar="FILE", help="topics → sensors (TOML; README)")
    p.add_argument("--mqtt-config", metavar="FILE", help="login and TLS of the broker ([broker] table; README)")
    p.add_argument("--clock", choices=("wall", "payload"), default="wall",
                   help="event time runs with the wall clock, or with the latest payload time (a played-back "
                   "stream) (default: %(default)s)")
    p.add_argument("--lateness", type=non_negative_float, default=1.0, metavar="S",
                   help="how late (s of event time) a message may come and still be published in order "
                   "(default: %(default)s)")
    p.add_argument("--clock-period", type=positive_float, default=0.5, metavar="S",
                   help="s of event time between clock ticks (default: %(default)s)")
    p.add_argument("--max-rate", type=positive_float, default=20.0, metavar="N",
                   help="messages per s of event time one sensor may send; more is a flood, dropped and counted "
                   "(default: %(default)s)")
    p.add_argument("--end-topic", metavar="TOPIC", help="a message on TOPIC ends the stream (a played-back session)")
    p.add_argument("--max-ahead", type=int_at_least(1), default=16, metavar="N",
                   help="clock ticks that may be unacknowledged by the slowest service (default: %(default)s)")
    p.add_argument("--wait-for", action="append", default=[], metavar="SERVICE[,SERVICE…]",
                   help="take no message until each of these services holds a liveliness token (NAME*N: N of them)")
    p.add_argument("--ready-timeout", type=positive_float, default=60.0, metavar="S",
                   help="how long to wait for the --wait-for services, s (default: %(default)s)")
    p.add_argument("--id", help="instance id (default: host-pid); also names the persistent MQTT session")
    p.add_argument("-v", "--verbose", action="store_true", help="debug logging")
