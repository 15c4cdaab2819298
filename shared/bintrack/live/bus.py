"""The Zenoh side of bintrack: session options, the bounded bridge from Zenoh's threads to
asyncio, and the runtime every service shares (liveliness, bad payloads, progress, shutdown).

Zenoh callbacks run on Zenoh's threads; they must neither block nor call the Zenoh API
(DESIGN §3). A service has one subscriber where cross-key order matters — by default on its
whole network (see :meth:`Service.subscribe`) — and hears only other sessions' samples
(``allowed_origin=REMOTE``: never its own puts). The callback hands samples to the
service's asyncio loop in batches (one ``loop.call_soon_threadsafe`` per wake-up) through an
:class:`Inbox` that holds at most ``capacity`` samples: past that, a sample is dropped and
counted instead of queued without bound. A dropped transition shows as a ``seq`` gap, which
the receiver repairs from the sensor's ``state`` queryable.

Flow control (keys beyond DESIGN §3, under ``control/``): after each clock tick a service has
processed it publishes ``control/progress/<service>/<id>`` (a ``Clock``); at end of stream,
once its own upstream services are done, it publishes ``control/done/<service>/<id>`` (an
``EndOfStream``). Replay stays a bounded event-time window ahead of the slowest service.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import math
import os
import signal
import socket
import threading
import time
from collections import defaultdict, deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import zenoh

from bintrack.errors import CommandError
from bintrack.keys import Keys, parse_key
from bintrack.live import checkpoint
from bintrack.live.control_guard import guard_control
from bintrack.messages import Clock, EndOfStream, Message, MessageError, decode, decode_view, encode

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
DEFAULT_INBOX = 65536
DEFAULT_MAX_PAYLOAD = 64 * 1024  # bytes; no bintrack message comes near it
MAX_SENDERS_LOGGED = 1024  # distinct senders of bad payloads named in the log; past that only counted
PARENT_ENV = "BINTRACK_PARENT_PID"  # set by a supervisor (bintrack up): the service ends when that process does
STATE_DIR_OPTION = "--state-dir"
ACK_TICKS = 8  # progress reports pending at most (replay's --max-ahead must be at least this to never wait) …
ACK_WAIT = 0.005  # … or s of wall clock since the last report, whichever comes first
ROUTE_CACHE = 65536  # distinct keys whose handlers are remembered (a bound against key floods)
GUARDED_KINDS = frozenset({"clock", "eos", "progress", "done"})  # what the control guard checks
PARENT_CHECK = 1.0  # s between checks that the supervisor is still there
CHECKPOINT_INTERVAL = 1.0  # s of wall clock between two throttled checkpoints …
CHECKPOINT_SPAN = 8.0  # … or s of event time, whichever comes first (well inside the sensors' HISTORY_SPAN)

log = logging.getLogger("bintrack")


# --------------------------------------------------------------------------- session options


def add_bus_arguments(parser: argparse.ArgumentParser, *, net_default: str | None = "default") -> None:
    """The Zenoh examples' options, plus the network name and how long to wait for the router."""
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
    group.add_argument(STATE_DIR_OPTION, metavar="DIR",
                       help="keep a checkpoint of this instance (named by --id) in DIR and resume from it after "
                       "a restart (default: none)")


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
    return config


def open_session(config: zenoh.Config, wait: float = 60.0, who: str = "bintrack",
                 stop: threading.Event | None = None) -> zenoh.Session:
    """Open a session, retrying while the router is not up yet, with a clear message.

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
            if time.monotonic() >= deadline or (stop is not None and stop.is_set()):
                raise ConnectionError(f"{who}: no Zenoh router reachable after {attempt} attempts: {reason}") from None
            if attempt == 1 or attempt % 10 == 0:
                log.warning("%s: waiting for the Zenoh router (%s); retrying", who, reason)
            if stop is not None:
                stop.wait(0.5)
            else:
                time.sleep(0.5)


# --------------------------------------------------------------------------- Zenoh → asyncio


class Inbox:
    """Bounded, non-blocking bridge from Zenoh callbacks to asyncio handlers, in arrival order.

    Zenoh threads append (handler, item) to one deque; the first item after the loop last
    drained it schedules one wake-up (``loop.call_soon_threadsafe``), which hands up to
    ``DRAIN_BATCH`` items to their handlers and reschedules itself while more wait: one
    wake-up per batch, not per sample. At most ``capacity`` items wait; past that an item
    is dropped and counted in ``dropped``. A sample whose payload is larger than
    ``max_payload`` bytes is refused on the Zenoh thread, before it is copied or decoded,
    and counted in ``oversized``; ``on_oversized(key, size)`` is then called on the loop.
    Never blocks a Zenoh thread.
    """

    DRAIN_BATCH = 4096  # items handled per wake-up before the loop gets a turn

    def __init__(self, loop: asyncio.AbstractEventLoop, capacity: int = DEFAULT_INBOX,
                 max_payload: int = DEFAULT_MAX_PAYLOAD, on_oversized: Callable[[str, int], None] | None = None):
        self.loop = loop
        self.capacity = capacity
        self.max_payload = max_payload
        self.on_oversized = on_oversized
        self.dropped = 0
        self.oversized = 0
        self.wakeups = 0
        self._items: deque[tuple[Callable[[Any], None], Any]] = deque()
        self._scheduled = False
        self._lock = threading.Lock()  # for the counters only; the deque is thread-safe
        self._closed = False

    def callback(self, handler: Callable[[Any], None]) -> Callable[[Any], None]:
        """A Zenoh callback that delivers each item to ``handler`` on the asyncio loop."""
        items, limit = self._items, self.max_payload

        def on_zenoh_thread(item):
            payload = getattr(item, "payload", None)
            if payload is not None and len(payload) > limit:
                with self._lock:
                    self.oversized += 1
                if self.on_oversized is not None and not self._closed:
                    try:
                        self.loop.call_soon_threadsafe(self.on_oversized, str(item.key_expr), len(payload))
                    except RuntimeError:
                        pass
                return
            if self._closed:
                return
            if len(items) >= self.capacity:
                with self._lock:
                    self.dropped += 1
                return
            items.append((handler, item))
            if not self._scheduled:
                self._scheduled = True
                try:
                    self.loop.call_soon_threadsafe(self._drain)
                except RuntimeError:  # loop closed during shutdown
                    pass

        return on_zenoh_thread

    def _drain(self) -> None:
        # Reset first: an item appended from here on schedules another wake-up (never one lost).
        self._scheduled = False
        self.wakeups += 1
        items = self._items
        for _ in range(min(len(items), self.DRAIN_BATCH)):
            if self._closed:
                items.clear()
                return
            handler, item = items.popleft()
            try:
                handler(item)
            except Exception as exc:  # one bad handler call must not lose the rest of the batch
                self.loop.call_exception_handler({"message": f"Exception in handler {handler!r}", "exception": exc})
        if items and not self._scheduled:
            self._scheduled = True
            self.loop.call_soon(self._drain)

    def close(self) -> None:
        self._closed = True


# --------------------------------------------------------------------------- service runtime


@dataclass
class BadInput:
    """Bad payloads seen by a service: counted by reason (the first words, a bounded set),
    logged once per sender for the first MAX_SENDERS_LOGGED senders."""

    service: str
    counts: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    _logged: set[str] = field(default_factory=set)

    def report(self, sender: str, reason: str) -> None:
        kind = reason.split(":")[0]
        self.counts[kind] += 1
        if sender not in self._logged and len(self._logged) < MAX_SENDERS_LOGGED:
            self._logged.add(sender)
            if len(self._logged) == MAX_SENDERS_LOGGED:
                log.warning("%s: bad payloads from %d senders; further senders are only counted",
                            self.service, MAX_SENDERS_LOGGED)
            log.warning("%s: dropped a bad payload from %s: %s (further ones from it are only counted)",
                        self.service, sender, reason)

    @property
    def total(self) -> int:
        return sum(self.counts.values())


class Service:
    """What every bintrack service shares: a session, a liveliness token under ``alive/``,
    decoding with bad-input accounting, progress and done reports, and a clean shutdown on
    SIGINT/SIGTERM. Subclasses declare what they need in :meth:`setup` and react in handlers
    that run on the asyncio loop."""

    name = "service"

    def __init__(self, args: argparse.Namespace):
        self.args = args
        self.keys = Keys(args.net)
        self.instance = getattr(args, "id", None) or f"{socket.gethostname()}-{os.getpid()}"
        self.run_id: str | None = None  # the run this instance belongs to (replay's; see load_checkpoint)
        self.bad = BadInput(self.name)
        self.session: zenoh.Session | None = None
        self.loop: asyncio.AbstractEventLoop | None = None
        self.inbox: Inbox | None = None
        self.stopping = asyncio.Event()
        self._stop_thread = threading.Event()
        self._declared: list[Any] = []
        self._routes: list[tuple[zenoh.KeyExpr, Callable[[zenoh.Sample], None]]] = []
        self._route_cache: dict[str, tuple[bool, tuple[Callable[[zenoh.Sample], None], ...]]] = {}
        self._network_subscriber = None
        self._token = None
        self._progress: Clock | None = None  # a progress report not sent yet
        self._unreported = 0
        self._reported_at = -math.inf
        self._checkpointed_at = -math.inf  # monotonic time of the last throttled checkpoint
        self._checkpointed_t = -math.inf  # event time (s) it was taken at
        self._progress_timer: asyncio.TimerHandle | None = None
        self.exit_status = 0
        self.routers: set[str] = set()  # the routers this session is connected to
        self.router_lost_at: float | None = None  # monotonic time the last router went, while none is back

    # -- to override ---------------------------------------------------------------------

    async def setup(self) -> None:
        """Declare subscribers, queryables and publishers (the token is declared after)."""

    async def main(self) -> None:
        """Run until stopped (default: wait for a stop signal)."""
        await self.stopping.wait()

    async def teardown(self) -> None:
        """Last words before the session closes."""

    def on_router_lost(self) -> None:
        """The session lost its last router (called on the loop; the token is withdrawn)."""

    async def on_router_back(self) -> None:
        """A router is back after a loss: fetch what went missing (the token is declared after)."""

    # -- helpers ---------------------------------------------------------------------------

    def listen_key(self) -> str:
        """The key expression of this service's one subscriber: everything its handlers need,
        in one subscriber so that each publisher's samples arrive in the order sent."""
        return self.keys.all()

    def subscribe(self, key_expr: str, handler: Callable[[zenoh.Sample], None]) -> None:
        """Call ``handler`` on the asyncio loop for every sample whose key ``key_expr`` includes.

        A service has one Zenoh subscriber, on :meth:`listen_key` (its whole network unless a
        subclass narrows it), and routes samples to handlers itself: Zenoh delivers one
        subscriber's samples in the order each publisher sent them, but calls different
        subscribers from different threads, so separate subscribers could see a publisher's
        messages on two keys swapped. It hears other sessions only (its own puts are not
        delivered back to it).
        """
        assert self.session is not None and self.inbox is not None
        pattern = zenoh.KeyExpr(key_expr)
        if not zenoh.KeyExpr(self.listen_key()).includes(pattern):
            raise ValueError(f"{key_expr} is outside this service's subscription {self.listen_key()}")
        self._routes.append((pattern, handler))
        self._route_cache.clear()
        if self._network_subscriber is None:
            self.guard = guard_control(self)
            self._network_subscriber = self.session.declare_subscriber(
                self.listen_key(), self.inbox.callback(self._route), allowed_origin=zenoh.Locality.REMOTE)
            self._declared.append(self._network_subscriber)

    def _route(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        entry = self._route_cache.get(key)
        if entry is None:
            entry = self._route_entry(key)
        guarded, handlers = entry
        if guarded and not self.guard.admit(sample):  # clock and control/* only from their token holders
            return
        for handler in handlers:
            handler(sample)

    def _route_entry(self, key: str) -> tuple[bool, tuple[Callable[[zenoh.Sample], None], ...]]:
        """(whether the control guard must see it, the handlers) of a concrete key, kept per
        key (the keys of a network are few: no key-expression matching per sample)."""
        expr = zenoh.KeyExpr(key)
        handlers = tuple(handler for pattern, handler in self._routes if pattern.includes(expr))
        try:
            guarded = parse_key(key).kind in GUARDED_KINDS
        except ValueError:
            guarded = False
        if len(self._route_cache) >= ROUTE_CACHE:
            self._route_cache.clear()
        entry = self._route_cache[key] = (guarded, handlers)
        return entry

    def serve(self, key_expr: str, handler: Callable[[zenoh.Query], None]) -> None:
        """A queryable whose queries are answered on the asyncio loop; each query is dropped
        (finalised) after the handler replied."""
        assert self.session is not None and self.inbox is not None

        def answer(query: zenoh.Query) -> None:
            try:
                handler(query)
            finally:
                query.drop()

        self._declared.append(self.session.declare_queryable(key_expr, self.inbox.callback(answer)))

    def publish(self, key_expr: str, message: Message) -> None:
        """Put ``message`` on ``key_expr``. It waits while the way to the router is full rather
        than drop (Zenoh's default for puts): a burst, such as a tracker's outputs at the end of
        a stream, must reach the recorder whole."""
        self.put(key_expr, encode(message))

    def put(self, key_expr: str, payload: bytes) -> None:
        """Put an encoded message on ``key_expr`` (waits while the way is full, as :meth:`publish`)."""
        assert self.session is not None
        self.session.put(key_expr, payload, congestion_control=zenoh.CongestionControl.BLOCK)

    def decode(self, cls: type, sample: zenoh.Sample):
        """The message in ``sample``, or None (counted and logged once per sender) if bad."""
        try:
            return decode(cls, sample.payload.to_bytes())
        except MessageError as exc:
            self.bad.report(str(sample.key_expr), exc.reason)
            return None

    def read(self, cls: type, sample: zenoh.Sample):
        """As :meth:`decode`, but a hot message (RawSample, Transition, Clock, EndOfStream) comes
        as a read-only view with the same fields (:func:`bintrack.messages.decode_view`)."""
        try:
            return decode_view(cls, sample.payload.to_bytes())
        except MessageError as exc:
            self.bad.report(str(sample.key_expr), exc.reason)
            return None

    def report_progress(self, t: float, sent: int | None = None, released: float | None = None) -> None:
        """Report the clock tick ``t`` (s) handled (and, for a sensor agent, the transitions
        ``sent``; for a tracker service, the watermark ``released``, s). Sent at once if
        ACK_WAIT s passed since the last report or ACK_TICKS reports are pending, else within
        ACK_WAIT s (the newest one): a report per tick at real time, one per few ticks when
        replay runs as fast as it can, and never a tick left unacknowledged."""
        self._progress = Clock(t=t, sent=sent, released=released)
        self._unreported += 1
        if self._unreported >= ACK_TICKS or time.monotonic() - self._reported_at >= ACK_WAIT:
            self.flush_progress()
        elif self._progress_timer is None:
            self._progress_timer = self.loop.call_later(ACK_WAIT, self.flush_progress)

    def flush_progress(self) -> None:
        """Publish the pending progress report, if any."""
        if self._progress_timer is not None:
            self._progress_timer.cancel()
            self._progress_timer = None
        if self._progress is not None and not self.session.is_closed():
            self.publish(self.keys.progress(self.name, self.instance), self._progress)
        self._progress, self._unreported, self._reported_at = None, 0, time.monotonic()

    def report_done(self, t: float) -> None:
        self.flush_progress()  # the last progress goes before done
        self.publish(self.keys.done(self.name, self.instance), EndOfStream(t=t))

    def stop(self) -> None:
        self.stopping.set()
        self._stop_thread.set()

    def follow_end_of_stream(self, upstream: Iterable[str], finish: Callable[[float], None]) -> None:
        """Once ``control/eos`` has arrived and every live instance of the ``upstream`` services
        has reported done, call ``finish(t)`` (flush, publish the last results) and report done.

        Upstream instances are followed through their liveliness tokens, so a service with no
        live upstream finishes at EOS directly.
        """
        assert self.session is not None and self.inbox is not None
        tracker = UpstreamDone(upstream)
        eos: list[float] = []
        finished = []

        def check() -> None:
            if eos and not finished and tracker.complete:
                finished.append(True)
                finish(eos[0])
                self.report_done(eos[0])

        def on_alive(sample: zenoh.Sample) -> None:
            tracker.on_liveliness(str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)
            check()

        def on_done(sample: zenoh.Sample) -> None:
            message = self.decode(EndOfStream, sample)
            if message is not None:
                parsed = parse_key(str(sample.key_expr))
                tracker.on_done(parsed.service, parsed.instance, message.t)
                check()

        def on_eos(sample: zenoh.Sample) -> None:
            message = self.decode(EndOfStream, sample)
            if message is not None and not eos:
                eos.append(message.t)
                check()

        self._declared.append(self.session.liveliness().declare_subscriber(
            self.keys.alive(), self.inbox.callback(on_alive), history=True))
        self.subscribe(self.keys.done(), on_done)
        self.subscribe(self.keys.eos(), on_eos)

    def query(self, key_expr: str, timeout: float = 2.0) -> list[bytes]:
        """Payloads of every reply to a get on ``key_expr``, in order (no consolidation: replies
        on one key are all kept); blocking, call via to_thread off setup."""
        assert self.session is not None
        replies = self.session.get(key_expr, timeout=timeout, consolidation=zenoh.ConsolidationMode.NONE)
        return [r.ok.payload.to_bytes() for r in replies if r.ok is not None]

    def _deployment_replies(self) -> list[tuple[bytes, str | None]]:
        """(payload, run id in its attachment or None) of each answer of the deployment queryable."""
        replies = self.session.get(self.keys.deployment(), timeout=1.0)
        return [(r.ok.payload.to_bytes(),
                 None if r.ok.attachment is None else r.ok.attachment.to_bytes().decode(errors="replace"))
                for r in replies if r.ok is not None]

    async def wait_for_deployment(self):
        """The deployment from the ``deployment`` queryable, retried until it answers."""
        from bintrack.messages import Deployment

        warned = False
        while not self.stopping.is_set():
            for payload, run in await asyncio.to_thread(self._deployment_replies):
                try:
                    deployment = decode(Deployment, payload)
                except MessageError as exc:
                    self.bad.report(self.keys.deployment(), exc.reason)
                    continue
                self.run_id = run
                return deployment
            if not warned:
                log.info("%s: waiting for the deployment on %s", self.name, self.keys.deployment())
                warned = True
            await asyncio.sleep(0.3)
        return None

    # -- lifecycle -------------------------------------------------------------------------

    def checkpoint_path(self) -> str | None:
        """Where this instance keeps its checkpoint (``--state-dir``/<service>-<id>.pickle), or None."""
        folder = getattr(self.args, "state_dir", None)
        return None if not folder else os.path.join(folder, f"{self.name}-{self.instance}.pickle")

    def load_checkpoint(self):
        """The object saved by :meth:`save_checkpoint` before a restart, or None: none saved, or
        refused (logged; the service starts afresh) because it is unsafe or damaged, or of an
        earlier run. A run is replay's: it names it in its answers on ``deployment``, and a
        service that asked for the deployment first (every one but replay) keeps only a
        checkpoint of the same run, so a stack started afresh on an old state folder (a compose
        volume) does not resume what another run left. Replay resumes its own run."""
        path = self.checkpoint_path()
        if path is None:
            return None
        try:
            saved = checkpoint.load_checkpoint(path)
        except checkpoint.CheckpointRefused as exc:
            log.warning("%s: checkpoint %s %s; starting afresh", self.name, path, exc)
            return None
        if saved is None:
            return None
        if not isinstance(saved, dict) or set(saved) != {"run", "state"}:
            log.warning("%s: checkpoint %s is not of this version; starting afresh", self.name, path)
            return None
        if self.run_id is not None and saved["run"] != self.run_id:
            log.warning("%s: checkpoint %s is of another run (%s; replay's is %s); starting afresh",
                        self.name, path, saved["run"], self.run_id)
            return None
        self.run_id = saved["run"]
        log.info("%s %s: restarted; resuming from its checkpoint", self.name, self.instance)
        return saved["state"]

    def save_checkpoint(self, state) -> None:
        """Save ``state`` with the run it belongs to, atomically and private to this user, if
        ``--state-dir`` is set."""
        path = self.checkpoint_path()
        if path is not None:
            checkpoint.save_checkpoint(path, {"run": self.run_id, "state": state})

    def save_checkpoint_throttled(self, t: float, state: Callable[[], Any]) -> None:
        """Save ``state()`` (as :meth:`save_checkpoint`) at event time ``t`` (s) if ``--state-dir``
        is set and CHECKPOINT_INTERVAL s of wall clock or CHECKPOINT_SPAN s of event time passed
        since the last one: for a state that takes long to save (a tracker's), whose outputs a
        restarted instance sends again and the receivers drop as duplicates."""
        now = time.monotonic()
        if self.checkpoint_path() is not None and (now - self._checkpointed_at >= CHECKPOINT_INTERVAL
                                                   or t - self._checkpointed_t >= CHECKPOINT_SPAN):
            self.save_checkpoint(state())
            self._checkpointed_at, self._checkpointed_t = now, t

    def _watch_router(self) -> None:
        """Log the loss and return of the router (Zenoh transport events). While it is lost the
        liveliness token is withdrawn, so replay holds its clock; once it is back the service
        fetches what it missed (:meth:`on_router_back`) and declares its token again."""
        self.routers = {str(zid) for zid in self.session.info.routers_zid()}

        def on_event(event) -> None:  # a Zenoh thread: hand over to the loop, nothing else
            if str(event.transport.whatami).lower() == "router":
                try:
                    self.loop.call_soon_threadsafe(self._router_event, event.kind == zenoh.SampleKind.PUT,
                                                   str(event.transport.zid))
                except RuntimeError:  # loop closed during shutdown
                    pass

        self._declared.append(self.session.info.declare_transport_events_listener(on_event, history=False))

    def _router_event(self, connected: bool, zid: str) -> None:
        if self.stopping.is_set():
            return
        if connected:
            self.routers.add(zid)
            if self.router_lost_at is not None:
                log.warning("%s: router %s reached again after %.1f s", self.name, zid[:8],
                            time.monotonic() - self.router_lost_at)
                self.router_lost_at = None
                asyncio.ensure_future(self._recover())
            return
        self.routers.discard(zid)
        if self.routers or self.router_lost_at is not None:
            return
        self.router_lost_at = time.monotonic()
        log.warning("%s: lost its router %s; waiting for it to come back", self.name, zid[:8])
        if self._token is not None:
            self._token.undeclare()
            self._token = None
            self._withdrawn = True
        self.on_router_lost()

    async def _recover(self) -> None:
        await self.on_router_back()
        if getattr(self, "_withdrawn", False) and self.router_lost_at is None and not self.stopping.is_set():
            self._withdrawn = False
            self._token = self.session.liveliness().declare_token(self.keys.alive(self.name, self.instance))

    def _watch_parent(self) -> None:
        """End with the supervisor: the kernel sends SIGTERM when it dies (Linux), and a check
        every PARENT_CHECK s covers the rest (a service re-parented is an orphan)."""
        parent = os.environ.get(PARENT_ENV)
        if not parent:
            return
        try:
            import ctypes

            ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass

        def check() -> None:
            if os.getppid() != int(parent):
                log.warning("%s: its supervisor (pid %s) is gone; stopping", self.name, parent)
                self.stop()
            elif not self.stopping.is_set():
                self.loop.call_later(PARENT_CHECK, check)

        check()

    async def _run(self) -> int:
        self.loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            self.loop.add_signal_handler(sig, self.stop)
        self._watch_parent()
        limit = getattr(self.args, "max_payload", None) or DEFAULT_MAX_PAYLOAD
        self.inbox = Inbox(self.loop, getattr(self.args, "inbox", DEFAULT_INBOX), limit,
                           lambda key, size: self.bad.report(key, f"too large: {size} bytes > {limit} (refused unread)"))
        try:
            config = zenoh_config(self.args)
        except ValueError as exc:
            log.error("%s: %s", self.name, exc)
            return 2
        try:
            self.session = await asyncio.to_thread(open_session, config, self.args.wait, self.name, self._stop_thread)
        except ConnectionError as exc:
            log.error("%s", exc)
            return 1
        try:
            self._watch_router()
            try:
                await self.setup()
            except CommandError as exc:  # the deployment does not suit this service's options
                log.error("%s: %s", self.name, exc)
                return 2
            if not self.stopping.is_set():
                self._token = self.session.liveliness().declare_token(self.keys.alive(self.name, self.instance))
                log.info("%s %s: ready on %s", self.name, self.instance, self.keys.prefix)
                await self.main()
            await self.teardown()
            return self.exit_status
        finally:
            self.inbox.close()
            for entity in reversed(self._declared):
                entity.undeclare()
            if self._token is not None:
                self._token.undeclare()
            self.session.close()
            if self.bad.total or self.inbox.dropped:
                log.warning("%s: %d bad payloads %s, %d dropped when the inbox was full", self.name,
                            self.bad.total, dict(self.bad.counts), self.inbox.dropped)

    def run(self) -> int:
        """Run the service to completion; returns the process exit status."""
        return asyncio.run(self._run())


def configure_logging(verbose: bool = False) -> None:
    logging.basicConfig(level=logging.DEBUG if verbose else logging.INFO,
                        format="%(asctime)s %(message)s", datefmt="%H:%M:%S")


def service_main(service_cls: type[Service], build_parser: Callable[[], argparse.ArgumentParser],
                 argv: list[str] | None = None) -> int:
    """Parse options, set up logging and run ``service_cls`` (the ``__main__`` of a service)."""
    args = build_parser().parse_args(argv)
    configure_logging(getattr(args, "verbose", False))
    return service_cls(args).run()


class UpstreamDone:
    """Which upstream services are alive and which reported done (end of stream).

    Feed it liveliness samples of ``alive/**`` and samples of ``control/done/**``;
    ``complete`` says every live instance of the watched services has reported done.
    """

    def __init__(self, services: Iterable[str]):
        self.services = set(services)
        self.alive: set[tuple[str, str]] = set()
        self.done: dict[tuple[str, str], float] = {}

    def on_liveliness(self, key: str, present: bool) -> None:
        parsed = parse_key(key)
        if parsed.kind == "alive" and parsed.service in self.services:
            entry = (parsed.service, parsed.instance)
            (self.alive.add if present else self.alive.discard)(entry)

    def on_done(self, service: str, instance: str, t: float) -> None:
        if service in self.services:
            self.done[(service, instance)] = t

    @property
    def complete(self) -> bool:
        return all(entry in self.done for entry in self.alive)

