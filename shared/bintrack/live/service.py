"""What every bintrack service is made of, and its life from start to stop.

A :class:`Service` is composed of parts, each with one job: the session's options
(:mod:`~bintrack.live.session_options`), the :class:`~bintrack.live.inbox.Inbox` from Zenoh's
threads to the loop, the one subscriber's :class:`~bintrack.live.dispatch.Dispatch` behind
the :class:`~bintrack.live.control_guard.ControlGuard`, the one
:class:`~bintrack.live.presence.Presence` of liveliness tokens, the
:class:`~bintrack.live.progress_reports.ProgressReports`, the
:class:`~bintrack.live.checkpoint.Checkpointer`, end of stream
(:class:`~bintrack.live.end_of_stream.EndOfStream`) and the router and parent watches. A
subclass declares what it needs in :meth:`Service.setup` and reacts in handlers that run on
the asyncio loop.
"""

from __future__ import annotations

import argparse
import asyncio
import faulthandler
import io
import logging
import os
import signal
import socket
import threading
from collections.abc import Callable, Iterable
from typing import Any

import zenoh

from bintrack.errors import CommandError
from bintrack.keys import Keys
from bintrack.live.bad_input import BadInput
from bintrack.live.checkpoint import Checkpointer
from bintrack.live.control_guard import ControlGuard
from bintrack.live.deployment_fetch import fetch_deployment
from bintrack.live.dispatch import Dispatch, Handler
from bintrack.live.end_of_stream import EndOfStream
from bintrack.live.inbox import DEFAULT_INBOX, Inbox
from bintrack.live.parent_watch import watch_parent
from bintrack.live.presence import OwnToken, Presence, token_present
from bintrack.live.progress_reports import ProgressReports
from bintrack.live.router_watch import RouterWatch
from bintrack.live.session_options import DEFAULT_MAX_PAYLOAD, open_session, zenoh_config
from bintrack.message_base import Message
from bintrack.message_codec import encode

log = logging.getLogger("bintrack")


class Service:
    """A session, a liveliness token under ``alive/``, decoding with bad-input accounting,
    progress and done reports, checkpoints, and a clean shutdown on SIGINT/SIGTERM."""

    name = "service"

    def __init__(self, args: argparse.Namespace):
        self.args = args
        self.keys = Keys(args.net)
        self.instance = getattr(args, "id", None) or f"{socket.gethostname()}-{os.getpid()}"
        self.bad = BadInput(self.name)
        self.session: zenoh.Session | None = None
        self.loop: asyncio.AbstractEventLoop | None = None
        self.inbox: Inbox | None = None
        self.stopping = asyncio.Event()
        self.exit_status = 0
        self._stop_thread = threading.Event()
        self._declared: list[Any] = []
        self.token = OwnToken(self.keys.alive(self.name, self.instance))
        self.guard = ControlGuard(self.keys, self.bad.report, lambda key: token_present(self.session, key))
        self.dispatch = Dispatch(self.listen_key(), self.guard)
        self.presence = Presence(self.keys, getattr(args, "stack", None), self.name)
        self.presence.listen(self.guard.on_presence)
        self.progress = ProgressReports(self.keys.progress(self.name, self.instance),
                                        self.keys.done(self.name, self.instance), self.publish,
                                        lambda: not self.session.is_closed())
        self.checkpoints = Checkpointer(getattr(args, "state_dir", None), self.name, self.instance)
        self.router_watch = RouterWatch(self.name, self.token.withdraw, lambda: self.token.declare(self.session),
                                        self.on_router_lost, self.on_router_back, self.stopping.is_set)

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

    def router_unreachable(self) -> None:
        """The first attempt to reach the router failed: what to do before waiting for it (in
        the thread opening the session; an exception ends the service)."""

    def listen_key(self) -> str:
        """The key expression of this service's one subscriber: everything its handlers need,
        in one subscriber so that each publisher's samples arrive in the order sent."""
        return self.keys.all()

    # -- the bus ---------------------------------------------------------------------------

    def subscribe(self, key_expr: str, handler: Handler) -> None:
        """Call ``handler`` on the asyncio loop for every sample whose key ``key_expr`` includes
        (see :mod:`bintrack.live.dispatch`)."""
        if self.dispatch.add(key_expr, handler):
            self.follow_presence()
            dispatch = self.dispatch
            route = self.inbox.callback(dispatch.route if dispatch.sensors_heard is None else dispatch.route_counted)
            for listen_key in self.dispatch.listen_keys:
                self._declared.append(self.session.declare_subscriber(listen_key, route,
                                                                      allowed_origin=zenoh.Locality.REMOTE))

    def narrow(self, listen_keys: list[str]) -> None:
        """Subscribe to ``listen_keys`` (a subscriber each) rather than to the whole network,
        before the first :meth:`subscribe`: a router then forwards this service only what they
        match (a region's part of the network). Samples of one publisher on two of them may
        arrive in either order (the service orders by counts, DESIGN §11)."""
        self.dispatch.narrow(listen_keys)

    def follow_presence(self, listener: Callable | None = None) -> None:
        """Follow the network's liveliness tokens (one subscriber), telling ``listener`` too."""
        self.presence.declare(self.session, self.inbox.callback)
        if listener is not None:
            self.presence.listen(listener)

    def serve(self, key_expr: str, handler: Callable[[zenoh.Query], None]) -> None:
        """A queryable whose queries are answered on the asyncio loop; each query is dropped
        (finalised) after the handler replied."""

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

    def put(self, key_expr: str, payload: bytes, attachment: bytes | None = None) -> None:
        """Put an encoded message on ``key_expr`` (waits while the way is full, as :meth:`publish`)."""
        self.session.put(key_expr, payload, congestion_control=zenoh.CongestionControl.BLOCK, attachment=attachment)

    def decode(self, cls: type, sample: zenoh.Sample):
        """The message in ``sample``, or None (counted and logged once per sender) if bad."""
        return self.bad.decode(cls, sample)

    def read(self, cls: type, sample: zenoh.Sample):
        """As :meth:`decode`, but a hot message (RawSample, Transition, Clock, EndOfStream) comes
        as a read-only view with the same fields (:func:`bintrack.message_codec.decode_view`)."""
        return self.bad.decode(cls, sample, view=True)

    def query(self, key_expr: str, timeout: float = 2.0) -> list[bytes]:
        """Payloads of every reply to a get on ``key_expr``, in order (no consolidation: replies
        on one key are all kept); blocking, call via to_thread off setup."""
        replies = self.session.get(key_expr, timeout=timeout, consolidation=zenoh.ConsolidationMode.NONE)
        return [r.ok.payload.to_bytes() for r in replies if r.ok is not None]

    async def wait_for_deployment(self):
        """The deployment from the ``deployment`` queryable, retried until it answers (None if
        stopped first); its run is the run this instance's checkpoints belong to."""
        fetched = await fetch_deployment(self)
        if fetched is None:
            return None
        deployment, self.checkpoints.run_id = fetched
        return deployment

    # -- flow control ------------------------------------------------------------------------

    def report_progress(self, t: float, sent: int | None = None, released: float | None = None,
                        sent_to: dict[str, int] | None = None) -> None:
        """See :meth:`ProgressReports.report`."""
        self.progress.report(t, sent, released, sent_to)

    def report_done(self, t: float) -> None:
        self.progress.done(t)

    def follow_end_of_stream(self, upstream: Iterable[str], finish: Callable[[float], None]) -> EndOfStream:
        """Once ``control/eos`` has arrived and every live instance of the ``upstream`` services
        has reported done, call ``finish(t)`` (flush, publish the last results) and report done.
        A service whose upstream never had a live instance finishes at EOS directly; an upstream
        service gone at the end is waited for (:data:`~bintrack.live.end_of_stream.END_GRACE`)."""
        return EndOfStream(self.name, upstream, finish, self.report_done).follow(self)

    # -- lifecycle -------------------------------------------------------------------------

    def stop(self) -> None:
        self.stopping.set()
        self._stop_thread.set()

    async def _run(self) -> int:
        self.loop = self.progress.loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            self.loop.add_signal_handler(sig, self.stop)
        watch_parent(self.loop, self.name, self.stop, self.stopping.is_set)
        limit = getattr(self.args, "max_payload", None) or DEFAULT_MAX_PAYLOAD
        self.inbox = Inbox(self.loop, getattr(self.args, "inbox", DEFAULT_INBOX), limit,
                           lambda key, size: self.bad.report(key, f"too large: {size} bytes > {limit} (refused unread)"))
        try:
            config = zenoh_config(self.args)
        except ValueError as exc:
            log.error("%s: %s", self.name, exc)
            return 2
        try:
            self.session = await asyncio.to_thread(open_session, config, self.args.wait, self.name, self._stop_thread,
                                                   self.router_unreachable)
        except ConnectionError as exc:
            log.error("%s", exc)
            return 1
        try:
            self._declared.append(self.router_watch.declare(self.session, self.loop))
            try:
                await self.setup()
            except CommandError as exc:  # the deployment does not suit this service's options
                log.error("%s: %s", self.name, exc)
                return 2
            if not self.stopping.is_set():
                self.token.declare(self.session)
                log.info("%s %s: ready on %s", self.name, self.instance, self.keys.prefix)
                await self.main()
            await self.teardown()
            return self.exit_status
        finally:
            self.inbox.close()
            self.presence.undeclare()
            for entity in reversed(self._declared):
                entity.undeclare()
            self.token.withdraw()
            self.session.close()
            if self.dispatch.sensors_heard is not None:
                log.info("%s: %s", self.name, self.dispatch.summary())
            if self.bad.total or self.inbox.dropped:
                log.warning("%s: %d bad payloads %s, %d dropped when the inbox was full", self.name,
                            self.bad.total, dict(self.bad.counts), self.inbox.dropped)

    def run(self) -> int:
        """Run the service to completion; returns the process exit status."""
        return asyncio.run(self._run())


def configure_logging(verbose: bool = False) -> None:
    """Log lines ``HH:MM:SS message`` on stderr; SIGUSR1 then writes every thread's Python stack
    there too, at once even when the process is stuck in Zenoh (``kill -USR1 PID`` asks a hung
    service where it is)."""
    logging.basicConfig(level=logging.DEBUG if verbose else logging.INFO,
                        format="%(asctime)s %(message)s", datefmt="%H:%M:%S")
    try:
        faulthandler.register(signal.SIGUSR1, all_threads=True)
    except (io.UnsupportedOperation, ValueError):  # stderr is not a file (a caller's capture): no dumps
        pass


def service_main(service_cls: type[Service], build_parser: Callable[[], argparse.ArgumentParser],
                 argv: list[str] | None = None) -> int:
    """Parse options, set up logging and run ``service_cls`` (the ``__main__`` of a service)."""
    args = build_parser().parse_args(argv)
    configure_logging(getattr(args, "verbose", False))
    return service_cls(args).run()
