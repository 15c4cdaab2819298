"""Replay: plays a dataset folder or a recording onto the bus (DESIGN §1, §3), flow-controlled.

    python -m bintrack.services.replay SOURCE [--speed X] [--loop] [--clock-period S]
        [--max-ahead N] [--max-gap S] [--wait-for SERVICE[,SERVICE…]] [--ready-timeout S] [--keys KEYEXPR]…
        [-m MODE] [-e ENDPOINT]… [-l ENDPOINT]… [-c FILE] [--cfg KEY:VALUE]… [--net NAME]

Serves the ``deployment`` queryable, waits for the ``--wait-for`` services, then executes
:func:`bintrack.live.replay_schedule.schedule`: a dataset's events as ``RawSample`` on
``raw/<sensor>`` (and its truth.csv rows, if any, as ``TruthSample`` on ``truth``), a recording's samples on their recorded keys with the payload bytes
unchanged; ``Clock`` ticks on ``clock``, each published only once every live consumer (any
service holding an ``alive/`` token, replays excepted) has reported progress up to the tick
``--max-ahead`` before it; at the end ``EndOfStream`` on ``control/eos``, said again to an
awaited service that comes back after it. Exits 0 once every live instance of the awaited
services has reported done after the (last) end of stream, 1 if they never came, 2 for a bad
source.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import secrets

import zenoh

from bintrack.argtypes import int_at_least, non_negative_float, positive_float
from bintrack.errors import CommandError
from bintrack.formats import FormatError
from bintrack.keys import Keys
from bintrack.live.control_guard import control_attachment
from bintrack.live.replay_gate import ReplayGate, wanted_services
from bintrack.live.checkpoint import ReplayCheckpoint
from bintrack.live.replay_player import ReplayPlayer
from bintrack.live.replay_schedule import MAX_GAP, TICK_FASTEST, TICK_WALL, default_clock_period, schedule
from bintrack.live.replay_source import ReplaySource
from bintrack.live.service import Service, service_main
from bintrack.live.session_options import add_bus_arguments
from bintrack.message_codec import encode

log = logging.getLogger("bintrack")



def _key_expr(text: str) -> str:
    try:
        return str(zenoh.KeyExpr(text))
    except Exception as exc:  # zenoh.ZError
        raise argparse.ArgumentTypeError(f"not a key expression: {text!r} ({exc})") from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("source", metavar="SOURCE", help="dataset folder, or a recording (FILE.mcap)")
    parser.add_argument("--speed", type=non_negative_float, default=1.0, metavar="X",
                        help="event time runs X times real time; 0 = as fast as flow control allows (default: %(default)s)")
    parser.add_argument("--loop", action="store_true",
                        help="play again after the end, shifted in event time so that it keeps increasing")
    parser.add_argument("--clock-period", type=positive_float, default=None, metavar="S",
                        help=f"event time between clock ticks, s (default: {TICK_WALL:g} s of wall clock at --speed, "
                        f"from {TICK_WALL:g} to {TICK_FASTEST:g} s of event time; {TICK_FASTEST:g} at --speed 0)")
    parser.add_argument("--max-ahead", type=int_at_least(1), default=16, metavar="N",
                        help="clock ticks that may be unacknowledged by the slowest service (default: %(default)s)")
    parser.add_argument("--wait-for", action="append", default=[], metavar="SERVICE[,SERVICE…]",
                        help="publish nothing until each of these services holds a liveliness token (SERVICE*N: N "
                        "instances of it); repeatable")
    parser.add_argument("--no-hold", dest="hold", action="store_false",
                        help="once they were all there, do not hold event time while a --wait-for service is gone (as "
                        "sensors in the field would not): one that comes back catches up from what the others hold, "
                        "and names what it could not")
    parser.add_argument("--ready-timeout", type=positive_float, default=60.0, metavar="S",
                        help="how long to wait for the --wait-for services, s (default: %(default)s)")
    parser.add_argument("--keys", action="append", default=[], type=_key_expr, metavar="KEYEXPR",
                        help="replay only samples whose recorded key matches, repeatable, e.g. 'bintrack/*/raw/**' "
                        "(clock ticks are always replayed)")
    parser.add_argument("--max-gap", type=positive_float, default=MAX_GAP, metavar="S",
                        help="jump over a gap in event time longer than S seconds (logged) instead of ticking and "
                        "pacing through it (default: %(default)s)")
    parser.add_argument("--salvage", action="store_true",
                        help="play a recording with bad chunks anyway: the sound ones, saying in one line what was lost "
                        "(without it a corrupt recording is refused, exit 2)")
    parser.add_argument("--id", help="instance id (default: host-pid)")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    add_bus_arguments(parser, net_default=None)
    parser.epilog = ("--net defaults to the deployment's name for a dataset and to the recorded network for a "
                     "recording (whose keys are then moved to --net).")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m bintrack.services.replay",
                                     description="Play a dataset or a recording onto the bus, flow-controlled.")
    add_arguments(parser)
    return parser


class Replay(Service):
    """The replay service; raises FormatError/CommandError on construction for a bad source."""

    name = "replay"

    def __init__(self, args: argparse.Namespace):
        self.source = ReplaySource(args.source, args.keys, args.max_ahead + 2, getattr(args, "salvage", False))
        args.net = args.net or self.source.net
        if args.clock_period is None:
            args.clock_period = default_clock_period(args.speed)
        try:
            Keys(args.net)
        except ValueError as exc:
            raise CommandError(f"{exc}; give a network name with --net") from None
        super().__init__(args)
        if self.source.recording is not None and self.source.recording.note():
            log.warning("replay: %s", self.source.recording.note())
        self.source.play_on(self.keys)
        self.gate = ReplayGate(wanted_services(args.wait_for), lambda: self.router_watch.lost_at is not None, self.stopping, args.hold)
        self.player: ReplayPlayer | None = None  # made in setup, once the run is known
        self.checked: asyncio.Task | None = None  # every row of the source read, while the others start

    def router_unreachable(self) -> None:
        """No router yet: read every row now, so that a bad source is said at once."""
        self.source.check()

    def listen_key(self) -> str:
        """Replay hears only the services' progress and done reports (not the traffic it causes)."""
        return f"{self.keys.prefix}/control/*/*/*"

    async def setup(self) -> None:
        checkpoint = self.checkpoints.load(ReplayCheckpoint)
        if self.checkpoints.run_id is None:  # a fresh start is a new run: the others keep only its checkpoints
            self.checkpoints.run_id = secrets.token_hex(8)
        payload, run = encode(self.source.deployment), self.checkpoints.run_id.encode()
        self.serve(self.keys.deployment(), lambda query: query.reply(self.keys.deployment(), payload, attachment=run))
        self.checked = asyncio.create_task(asyncio.to_thread(self.source.check))
        plan = iter(schedule(self.source.items, period=self.args.clock_period, max_ahead=self.args.max_ahead,
                             recorded_ticks=self.source.recording is not None, loop=self.args.loop,
                             max_gap=self.args.max_gap))
        self.player = ReplayPlayer(plan, self.source, self.gate, self.keys, self.put, self.checkpoints.save,
                                   self.stopping, self.args.speed, self.args.loop)
        if checkpoint is not None:
            self.player.resume(checkpoint)
        self.serve(self.keys.recent(), self._on_recent)  # complete from here on, even after a restart
        # the services already up come first (a get after subscribing could time out empty on a
        # loaded machine, and a restarted replay then waited for services that were up)
        self.gate.follow(self)
        try:  # the others fetch the deployment and start meanwhile; a bad row is one line, before "ready"
            await self.checked
        except ValueError as exc:  # FormatError
            raise CommandError(str(exc)) from None

    def _on_recent(self, query: zenoh.Query) -> None:
        """``control/recent?after=T``: see :meth:`ReplaySource.recent_answer`."""
        try:
            after = float(query.parameters.get("after") or "-inf")
        except ValueError:
            query.reply_err(b"after must be a number of seconds")
            return
        for payload in self.source.recent_answer(after):
            query.reply(self.keys.recent(), payload)

    def stop(self) -> None:
        super().stop()
        self.gate.changed.set()

    def _control(self) -> bytes:
        """The attachment of this replay's clock and end of stream (see control_guard). The step
        it announces is the largest between two ticks a receiver may see: up to --max-ahead
        ticks may be in flight, and lost together with the router."""
        step = self.source.largest_step(self.args.clock_period, self.args.max_gap)
        return control_attachment(self.name, self.instance, step * self.args.max_ahead)

    async def main(self) -> None:
        gate = self.gate
        if gate.wanted:
            if not await gate.all_present(self.args.ready_timeout):
                if not self.stopping.is_set():
                    log.error("replay: no liveliness token from %s on %s after %g s; is it running on this network?",
                              ", ".join(gate.missing()), self.keys.alive(), self.args.ready_timeout)
                    self.exit_status = 1
                self.checked.cancel()
                return
        gate.started = True
        try:
            await self.checked  # every row read (and found good) before anything is published
            warning = self.source.span.warning(f"{self.args.source}/events.csv") if self.source.span else None
            if warning:
                log.warning("replay: %s", warning)
            await self.player.play(self._control())
        except ValueError as exc:  # FormatError, NothingToReplay, a recorded payload that is not msgpack
            log.error("replay: %s", exc)
            self.exit_status = 2

def main(argv: list[str] | None = None) -> int:
    try:
        return service_main(Replay, build_parser, argv)
    except (FormatError, CommandError) as exc:
        log.error("replay: %s", exc)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
