"""Replay: plays a dataset folder or a recording onto the bus (DESIGN §1, §3), flow-controlled.

    python -m bintrack.services.replay SOURCE [--speed X] [--loop] [--clock-period S]
        [--max-ahead N] [--wait-for SERVICE[,SERVICE…]] [--ready-timeout S] [--keys KEYEXPR]…
        [-m MODE] [-e ENDPOINT]… [-l ENDPOINT]… [-c FILE] [--cfg KEY:VALUE]… [--net NAME]

Serves the ``deployment`` queryable, waits for the ``--wait-for`` services, then executes
:func:`bintrack.live.replay_schedule.schedule`: a dataset's events as ``RawSample`` on
``raw/<sensor>`` (and its truth.csv rows, if any, as ``TruthSample`` on ``truth``), a recording's samples on their recorded keys with the payload bytes
unchanged; ``Clock`` ticks on ``clock``, each published only once every live consumer (any
service holding an ``alive/`` token, replays excepted) has reported progress up to the tick
``--max-ahead`` before it; at the end ``EndOfStream`` on ``control/eos``. Exits 0 after the
(last) end of stream, 1 if the awaited services never came, 2 for a bad source.
"""

from __future__ import annotations

import argparse
import asyncio
import heapq
import logging
import math
import secrets
import time
from collections import deque
from collections.abc import Callable, Iterable
from pathlib import Path

import zenoh

from bintrack.argtypes import int_at_least, non_negative_float, positive_float
from bintrack.live.bus import Service, add_bus_arguments, service_main
from bintrack.live.control_guard import control_attachment
from bintrack.errors import CommandError
from bintrack.formats import FormatError, TruthRow, open_dataset
from bintrack.keys import Keys, parse_key
from bintrack.messages import RESENT, Clock, EndOfStream, TruthSample, encode, encode_raw_sample
from bintrack.live.recording import Record, open_recording, replay_items, shift_payload
from bintrack.live.replay_schedule import (TICK_FASTEST, TICK_WALL, Consumers, End, Pacer, Publish, Tick,
                                           default_clock_period, schedule)

log = logging.getLogger("bintrack")

PROGRESS_INTERVAL = 5.0  # s of wall clock between progress lines
YIELD_EVERY = 0.002  # s of wall clock between two turns given to the loop while publishing (waits give more)




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
    parser.add_argument("--ready-timeout", type=positive_float, default=60.0, metavar="S",
                        help="how long to wait for the --wait-for services, s (default: %(default)s)")
    parser.add_argument("--keys", action="append", default=[], type=_key_expr, metavar="KEYEXPR",
                        help="replay only samples whose recorded key matches, repeatable, e.g. 'bintrack/*/raw/**' "
                        "(clock ticks are always replayed)")
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
        path = Path(args.source)
        if path.suffix == ".mcap":
            self.recording, self.dataset, self.truth = open_recording(path), None, []
            self.deployment, source_net = self.recording.deployment, self.recording.net
            self.total = None
        else:
            self.recording, self.dataset = None, open_dataset(path)
            self.deployment = self.dataset.deployment
            source_net = self.deployment.name
            self.total = sum(1 for _ in self.dataset.events())  # validates every row before anything is published
            # truth.csv, if the dataset has one, is published on `truth` (sorted by t; read and checked now)
            self.truth = sorted(self.dataset.truth(), key=lambda row: row.t) if self.dataset.has_truth else []
        args.net = args.net or source_net
        if args.clock_period is None:
            args.clock_period = default_clock_period(args.speed)
        try:
            Keys(args.net)
        except ValueError as exc:
            raise CommandError(f"{exc}; give a network name with --net") from None
        super().__init__(args)
        self.source_prefix = Keys(self.recording.net).prefix if self.recording is not None else None
        self.wanted = list(dict.fromkeys(name.strip() for item in args.wait_for for name in item.split(",") if name.strip()))
        self.wanted_missing = list(self.wanted)  # those of them with no live instance
        self.filters = [zenoh.KeyExpr(k) for k in args.keys]
        self._matches: dict[str, bool] = {}
        self.raw_keys: dict[str, str] = {}  # sensor id → its raw key
        self.alive: set[tuple[str, str]] = set()
        self.consumers = Consumers()
        self.last_tick: float | None = None
        self.published = 0
        self._changed = asyncio.Event()
        # (tick before it, key, payload) of the raw samples since the last few ticks, for ``recent``
        self.recent: deque[tuple[float, str, bytes]] = deque()
        self.recent_ticks: deque[float] = deque(maxlen=args.max_ahead + 2)
        self.resume_after: float | None = None
        self.plan = None  # the plan of the run (an iterator), made in setup
        self.pauses = 0

    # -- bus wiring -------------------------------------------------------------------------

    def listen_key(self) -> str:
        """Replay hears only the services' progress reports (not the traffic it causes)."""
        return self.keys.progress()

    async def setup(self) -> None:
        checkpoint = self.load_checkpoint()
        if self.run_id is None:  # a fresh start is a new run: the others keep only its checkpoints
            self.run_id = secrets.token_hex(8)
        payload, run = encode(self.deployment), self.run_id.encode()
        self.serve(self.keys.deployment(), lambda query: query.reply(self.keys.deployment(), payload, attachment=run))
        self.plan = iter(schedule(self._pass, period=self.args.clock_period, max_ahead=self.args.max_ahead,
                                  recorded_ticks=self.recording is not None, loop=self.args.loop))
        if checkpoint is not None:
            self.resume_after, self.published = checkpoint["tick"], checkpoint["published"]
            self._fast_forward()
        self.serve(self.keys.recent(), self._on_recent)  # complete from here on, even after a restart
        # history: the services already up come first (a get after subscribing could time out
        # empty on a loaded machine, and a restarted replay then waited for services that were up)
        self._declared.append(self.session.liveliness().declare_subscriber(
            self.keys.alive(), self.inbox.callback(self._on_alive), history=True))
        self.subscribe(self.keys.progress(), self._on_progress)

    def _on_recent(self, query: zenoh.Query) -> None:
        """``control/recent?after=T``: each raw sample published after the tick at T (s), in
        order, then a ``Clock`` (the last tick published) that ends the answer."""
        try:
            after = float(query.parameters.get("after") or "-inf")
        except ValueError:
            query.reply_err(b"after must be a number of seconds")
            return
        for tick, key, payload in self.recent:
            if tick >= after:
                query.reply(self.keys.recent(), payload)
        # last, the clock tick before the newest sample (0 before the first): the asker knows the
        # answer is complete
        query.reply(self.keys.recent(), encode(Clock(t=0.0 if self.last_tick is None else self.last_tick)))

    def _on_alive(self, sample: zenoh.Sample) -> None:
        try:
            parsed = parse_key(str(sample.key_expr))
        except ValueError:
            return
        entry = (parsed.service, parsed.instance)
        if sample.kind == zenoh.SampleKind.PUT:
            self.alive.add(entry)
            if parsed.service != self.name:
                self.consumers.appeared(entry, self.last_tick)
        else:
            self.alive.discard(entry)
            self.consumers.vanished(entry)
        self.wanted_missing = []
        for wanted in self.wanted:  # NAME, or NAME*N: N live instances of it
            name, _, count = wanted.partition("*")
            if sum(service == name for service, _ in self.alive) < (int(count) if count.isdigit() else 1):
                self.wanted_missing.append(wanted)
        self._changed.set()

    def _on_progress(self, sample: zenoh.Sample) -> None:
        message = self.read(Clock, sample)
        if message is not None:
            parsed = parse_key(str(sample.key_expr))
            self.consumers.reported((parsed.service, parsed.instance), message.t)
            self._changed.set()

    def stop(self) -> None:
        super().stop()
        self._changed.set()

    def _put(self, key: str, payload: bytes, attachment: bytes | None = None) -> None:
        self.session.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK, attachment=attachment)

    def _control(self) -> bytes:
        """The attachment of this replay's clock and end of stream (see control_guard). The step
        it announces is the largest between two ticks a receiver may see: up to --max-ahead
        ticks may be in flight, and lost together with the router."""
        step = self.args.clock_period
        if self.recording is not None:
            ticks = [t for t, item in replay_items(self.recording) if item is None]
            step = max([step, *(b - a for a, b in zip(ticks, ticks[1:]))])
        return control_attachment(self.name, self.instance, step * self.args.max_ahead)

    # -- the source -------------------------------------------------------------------------

    def _keep(self, key: str) -> bool:
        if not self.filters:
            return True
        if key not in self._matches:
            self._matches[key] = any(f.intersects(zenoh.KeyExpr(key)) for f in self.filters)
        return self._matches[key]

    def _pass(self) -> Iterable[tuple[float, object]]:
        if self.dataset is not None:
            events = ((e.t, e) for e in self.dataset.events() if not self.filters or self._keep(self.keys.raw(e.sensor)))
            if self.truth and self._keep(self.keys.truth()):
                # truth.csv rows beside the events in event time; an event before a truth row at the same t
                return heapq.merge(events, ((row.t, row) for row in self.truth), key=lambda item: item[0])
            return events
        return replay_items(self.recording, self._keep)

    def _publish(self, action: Publish, put: bool = True, attachment: bytes | None = None) -> None:
        """Publish the sample of ``action`` and keep a raw sample for ``recent``; with ``put``
        False only keep it (a restarted replay rebuilding what it had published). A raw sample
        goes with ``attachment`` (:data:`RESENT` or None)."""
        item = action.item
        if isinstance(item, Record):
            raw = item.kind == "raw"
            if put or raw:
                key = self.keys.prefix + item.key[len(self.source_prefix):]
                payload = shift_payload(item.payload, action.shift)
                if put:
                    self._put(key, payload, attachment if raw else None)
                if raw:
                    self._remember(key, payload)
        elif isinstance(item, TruthRow):
            if put:
                self._put(self.keys.truth(), encode(TruthSample(t=action.t, target=item.target, x=item.x, y=item.y)))
        else:
            key = self.raw_keys.get(item.sensor) or self.raw_keys.setdefault(item.sensor, self.keys.raw(item.sensor))
            payload = encode_raw_sample(action.t, item.sensor, item.value)
            if put:
                self._put(key, payload, attachment)
            self._remember(key, payload)

    def _remember(self, key: str, payload: bytes) -> None:
        """Keep a raw sample put after the last tick, for ``recent`` and for sending it again."""
        self.recent.append((-math.inf if self.last_tick is None else self.last_tick, key, payload))

    def _ticked(self, t: float, save: bool = True) -> None:
        """After the tick at ``t``: forget samples older than any consumer can still need (it has
        acknowledged a tick at most max_ahead ticks back) and checkpoint the position."""
        self.last_tick = t
        self.recent_ticks.append(t)
        oldest = self.recent_ticks[0]
        while self.recent and self.recent[0][0] < oldest:
            self.recent.popleft()
        if save:
            self.save_checkpoint({"tick": t, "published": self.published})

    def _fast_forward(self) -> None:
        """After a restart: walk the plan up to the tick the previous instance checkpointed,
        publishing nothing but keeping the raw samples of the last ticks, so that ``recent``
        answers a restarted sensor agent at once, before the stack is complete again (the
        others wait for this replay's answer; it waits for them)."""
        for action in self.plan:
            if isinstance(action, Tick):
                self._ticked(action.t, save=False)
                if action.t >= self.resume_after:
                    return
            elif isinstance(action, Publish):
                self._publish(action, put=False)

    def _send_again(self) -> int:
        """After a restart, before anything new: put the raw samples of the last ticks again,
        marked :data:`RESENT`. The killed instance checkpointed each tick once it had put it,
        but what it put last may still have been in its send path; every consumer has
        acknowledged the ticks before these, so nothing older can be missing. How many."""
        for _, key, payload in self.recent:
            self._put(key, payload, RESENT)
        return len(self.recent)

    def _missing(self) -> list[str]:
        """The --wait-for services with no live instance, and the router if it is lost."""
        missing = self.wanted_missing
        return missing + ["the router"] if self.router_lost_at is not None else missing

    async def _hold_while_missing(self, t: float) -> bool:
        """While an awaited service has no live instance (it died, or lost the router), hold the
        clock; True once all are back (False if stopping)."""
        if not self._missing():
            return True
        gone = ", ".join(self._missing())
        self.pauses += 1
        log.warning("replay: %s gone; holding event time at t=%.3f s until it is back", gone, t)
        started = time.monotonic()
        if not await self._until(lambda: not self._missing(), lambda: "services " + ", ".join(self._missing())):
            return False
        held = time.monotonic() - started
        self.pacer.hold(held)
        log.info("replay: %s back after %.1f s; resuming at t=%.3f s", gone, held, t)
        return True

    # -- the run ----------------------------------------------------------------------------

    async def _until(self, condition: Callable[[], bool], waiting_for: Callable[[], str],
                     timeout: float | None = None) -> bool:
        """Wait until ``condition()`` holds (True), the service stops or ``timeout`` s pass (False);
        says what it waits for every few seconds."""
        start = last_said = time.monotonic()
        while not condition():
            if self.stopping.is_set():
                return False
            now = time.monotonic()
            if timeout is not None and now - start >= timeout:
                return False
            if now - last_said >= PROGRESS_INTERVAL:
                log.info("replay: waiting for %s", waiting_for())
                last_said = now
            self._changed.clear()
            try:
                await asyncio.wait_for(self._changed.wait(), 1.0)
            except TimeoutError:
                pass
        return True

    async def _ready_for(self, action, skip_ack: bool) -> bool:
        """Wait until every awaited service is live and, for a tick or the end, has acknowledged
        what it must; False if stopping. (A consumer that dies no longer owes its
        acknowledgement, so liveness is checked again after it.)"""
        while True:
            if not await self._hold_while_missing(action.t):
                return False
            if not isinstance(action, Publish) and action.ack is not None and not skip_ack:
                if not await self._acknowledged(action.ack):
                    return False
            if not self._missing():
                return True

    async def _acknowledged(self, ack: float) -> bool:
        return await self._until(lambda: not self.consumers.owing(ack),
                                 lambda: f"progress >= {ack:g} s from "
                                 + ", ".join(f"{s}/{i}" for s, i in self.consumers.owing(ack)))

    async def main(self) -> None:
        if self.wanted:
            missing = self._missing
            if not await self._until(lambda: not missing(), lambda: "services " + ", ".join(missing()),
                                     self.args.ready_timeout):
                if not self.stopping.is_set():
                    log.error("replay: no liveliness token from %s on %s after %g s; is it running on this network?",
                              ", ".join(missing()), self.keys.alive(), self.args.ready_timeout)
                    self.exit_status = 1
                return
        try:
            await self._play()
        except ValueError as exc:  # FormatError, NothingToReplay, a recorded payload that is not msgpack
            log.error("replay: %s", exc)
            self.exit_status = 2

    async def _play(self) -> None:
        self.pacer = pacer = Pacer(self.args.speed)
        control = self._control()
        started = last_said = yielded_at = time.monotonic()
        skip_ack = False
        if self.resume_after is not None:  # a restart: what the previous instance published is done
            resent = self._send_again()
            log.info("replay: restarted; resuming after the tick at t=%g s (%d samples were published); sent "
                     "the %d raw samples of its last %d ticks again, and marks those up to its next tick "
                     "(receivers keep those they lack)", self.resume_after, self.published, resent,
                     len(self.recent_ticks))
            self.resume_after, skip_ack, again = None, True, RESENT
        else:
            again = None
        for action in self.plan:
            quick = isinstance(action, Publish) and not self.wanted_missing and self.router_lost_at is None
            if not quick and not await self._ready_for(action, skip_ack):  # (a sample owes no acknowledgement)
                break
            if not isinstance(action, Publish):
                skip_ack = False  # the progress owed to the previous instance went to it
            if isinstance(action, End):
                self._put(self.keys.eos(), encode(EndOfStream(t=action.t)), control)
                log.info("replay: end of stream at t=%g s after %d samples", action.t, self.published)
                if action.last:
                    return
                continue
            delay = pacer.delay(action.t, time.monotonic())
            if delay > 0:
                try:
                    await asyncio.wait_for(self.stopping.wait(), delay)
                except TimeoutError:
                    pass
            if self.stopping.is_set():
                break
            if isinstance(action, Tick):
                again = None
                self._put(self.keys.clock(), encode(Clock(t=action.t)), control)
                self._ticked(action.t)
                if time.monotonic() - yielded_at >= YIELD_EVERY:
                    await asyncio.sleep(0)  # let signals and progress reports in
                    yielded_at = time.monotonic()
            else:
                self._publish(action, attachment=again)  # (the killed instance may have put it)
                self.published += 1
            now = time.monotonic()
            if now - last_said >= PROGRESS_INTERVAL:
                total = f"/{self.total}" if self.total and not self.args.loop else ""
                log.info("replay: %d%s samples published, event time %.3f s, %.0f samples/s",
                         self.published, total, action.t, self.published / (now - started))
                last_said = now
        log.info("replay: stopped after %d samples", self.published)


def main(argv: list[str] | None = None) -> int:
    try:
        return service_main(Replay, build_parser, argv)
    except (FormatError, CommandError) as exc:
        log.error("replay: %s", exc)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
