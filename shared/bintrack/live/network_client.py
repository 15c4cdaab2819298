"""An asyncio client of a bintrack network, for other Python programs.

Connects to the Zenoh router of a deployment and reads the live results as decoded,
validated messages (:mod:`bintrack.bus_payloads`)::

    import asyncio
    from bintrack.client import BintrackClient

    async def main():
        async with BintrackClient(connect=["tcp/127.0.0.1:7447"]) as c:   # net: the one alive
            print(await c.latest_tracks(timeout=2.0))      # the base station's latest TrackSet, or None
            async for scan in c.tracks():                   # every TrackSet from now on
                for track in scan.tracks:
                    print(scan.t, track.track, track.x, track.y)

    asyncio.run(main())

Each of :meth:`BintrackClient.tracks`, :meth:`~BintrackClient.estimates` and
:meth:`~BintrackClient.transitions` declares a Zenoh subscriber at once and returns a
:class:`Subscription`, an async iterator. Samples go from Zenoh's threads to the asyncio loop
through a bounded :class:`bintrack.live.inbox.Inbox` (the callback neither blocks nor calls Zenoh);
each subscription then keeps at most ``capacity`` decoded messages for the reader and drops
the oldest past that, counting them in ``dropped``. A payload that does not decode or
validate is skipped and counted (``bad``), logged once per sender, and never raised into the
reader's loop. Iteration ends when the subscription or the client is closed.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
from collections import deque
from collections.abc import Iterable
from typing import Generic, TypeVar

import zenoh

from bintrack.live.bad_input import BadInput
from bintrack.live.inbox import DEFAULT_INBOX, Inbox
from bintrack.live.session_options import open_session, zenoh_config
from bintrack.keys import ROOT, Keys, parse_key
from bintrack.bus_payloads import LocalEstimate, TrackSet, Transition
from bintrack.message_base import Message
from bintrack.message_codec import MessageError, decode

DEFAULT_CAPACITY = 1024

log = logging.getLogger("bintrack")

M = TypeVar("M", bound=Message)


def alive_networks(session: zenoh.Session, timeout: float = 2.0) -> list[str]:
    """The networks with at least one service holding its liveliness token
    (``bintrack/<net>/alive/…``) on the bus, sorted (blocking)."""
    nets = set()
    for reply in session.liveliness().get(f"{ROOT}/*/alive/**", timeout=timeout):
        if reply.ok is not None:
            try:
                nets.add(parse_key(str(reply.ok.key_expr)).net)
            except ValueError:
                continue
    return sorted(nets)


def the_network(session: zenoh.Session, timeout: float = 2.0) -> str:
    """The one network alive on the bus; ValueError (one line) if there is none or several."""
    nets = alive_networks(session, timeout)
    if len(nets) == 1:
        return nets[0]
    if not nets:
        raise ValueError("no bintrack network is alive on the bus (no token under bintrack/*/alive); "
                         "start one (bintrack up) or give --net")
    raise ValueError(f"{len(nets)} networks are alive on the bus: {', '.join(nets)}; choose one with --net")


class Subscription(Generic[M]):
    """Decoded messages of type ``cls`` published on ``key_expr``, as an async iterator.

    Made by :class:`BintrackClient`; the subscriber is declared when this object is created,
    so nothing published after that is missed for want of a reader. Counters: ``received``
    (valid messages delivered to the buffer), ``bad`` (payloads skipped), ``dropped`` (oldest
    messages discarded because the reader fell ``capacity`` messages behind).
    """

    def __init__(self, client: BintrackClient, key_expr: str, cls: type[M], capacity: int):
        if capacity < 1:
            raise ValueError(f"capacity must be at least 1, got {capacity}")
        self.key_expr = key_expr
        self.cls = cls
        self.capacity = capacity
        self.received = 0
        self.bad = 0
        self.dropped = 0
        self._client = client
        self._buffer: deque[M] = deque()
        self._ready = asyncio.Event()
        self._closed = False
        self._subscriber = client._declare_subscriber(key_expr, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        """On the asyncio loop: decode, validate and buffer one sample."""
        if self._closed:
            return
        try:
            message = decode(self.cls, sample.payload.to_bytes())
        except MessageError as exc:
            self.bad += 1
            self._client.bad.report(str(sample.key_expr), exc.reason)
            return
        if len(self._buffer) >= self.capacity:
            self._buffer.popleft()
            self.dropped += 1
        self._buffer.append(message)
        self.received += 1
        self._ready.set()

    def __aiter__(self) -> Subscription[M]:
        return self

    async def __anext__(self) -> M:
        while not self._buffer:
            if self._closed:
                raise StopAsyncIteration
            self._ready.clear()
            await self._ready.wait()
        return self._buffer.popleft()

    def close(self) -> None:
        """Undeclare the subscriber; a reader waiting in ``async for`` then stops."""
        if self._closed:
            return
        self._closed = True
        self._buffer.clear()
        self._ready.set()
        self._client._forget(self)
        self._subscriber.undeclare()

    @property
    def closed(self) -> bool:
        return self._closed

    async def __aenter__(self) -> Subscription[M]:
        return self

    async def __aexit__(self, *exc_info) -> None:
        self.close()


class BintrackClient:
    """A Zenoh session on network ``net`` with decoding subscriptions and queries.

    Options mirror the services' bus options (:func:`bintrack.live.session_options.add_bus_arguments`):
    ``connect`` endpoints (default ``tcp/127.0.0.1:7447`` in client mode), ``mode``
    (``client``, ``peer`` or ``router``), ``listen`` endpoints, ``config`` (a Zenoh JSON5 file;
    default ``$ZENOH_CONFIG`` if set), ``cfg`` (``KEY:VALUE`` overrides) and ``wait`` (how long
    to keep retrying to reach the router, s). ``capacity`` bounds each subscription's buffer
    (messages) and ``inbox`` the samples in flight from Zenoh's threads to the loop.

    Use it as an async context manager (or call :meth:`open` and :meth:`close`)::

        async with BintrackClient(net="darpa-grid", connect=["tcp/10.0.0.5:7447"]) as c:
            async for estimate in c.estimates():
                print(estimate.node, estimate.x, estimate.y)

    Without ``net`` the client takes, when it opens, the one network alive on the bus (services
    holding liveliness tokens under ``bintrack/<net>/alive``). Opening raises ``ValueError`` for a
    bad configuration, or when no network or several are alive and ``net`` is not given (naming
    them), and ``ConnectionError`` when no router answers within ``wait`` seconds.
    """

    def __init__(self, net: str | None = None, connect: Iterable[str] | None = None, *,
                 mode: str | None = None, listen: Iterable[str] = (), config: str | None = None,
                 cfg: Iterable[str] = (), wait: float = 10.0, capacity: int = DEFAULT_CAPACITY,
                 inbox: int = DEFAULT_INBOX):
        self.keys: Keys | None = None if net is None else Keys(net)  # net None: found at open
        self.capacity = capacity
        self.wait = wait
        self.bad = BadInput("client")
        self._options = argparse.Namespace(mode=mode, connect=list(connect or []), listen=list(listen),
                                           config=config, cfg=list(cfg))
        self._inbox_capacity = inbox
        self._session: zenoh.Session | None = None
        self._inbox: Inbox | None = None
        self._subscriptions: list[Subscription] = []
        self._dropped_by_closed = 0  # drop-oldest counts of subscriptions already closed

    @classmethod
    def from_args(cls, args: argparse.Namespace, **kwargs) -> BintrackClient:
        """A client from the options of :func:`bintrack.live.session_options.add_bus_arguments`."""
        return cls(net=args.net, connect=args.connect, mode=args.mode, listen=args.listen,
                   config=args.config, cfg=args.cfg, wait=args.wait, **kwargs)

    # -- lifecycle -----------------------------------------------------------------------

    async def open(self) -> BintrackClient:
        """Open the Zenoh session (retrying for up to ``wait`` s while the router is not up)."""
        if self._session is not None:
            raise RuntimeError("client already open")
        config = zenoh_config(self._options)
        self._inbox = Inbox(asyncio.get_running_loop(), self._inbox_capacity)
        self._session = await asyncio.to_thread(open_session, config, self.wait, "bintrack client")
        if self.keys is None:
            try:
                self.keys = Keys(await asyncio.to_thread(the_network, self._session))
            except ValueError:
                await self.close()
                raise
        return self

    async def close(self) -> None:
        """Undeclare every subscription, then close the session. Safe to call twice."""
        if self._session is None:
            return
        self._inbox.close()
        for subscription in list(self._subscriptions):
            subscription.close()
        session, self._session = self._session, None
        session.close()
        if self.bad.total or self.dropped:
            log.warning("bintrack client: %d bad payloads %s, %d messages dropped", self.bad.total,
                        dict(self.bad.counts), self.dropped)

    async def __aenter__(self) -> BintrackClient:
        return await self.open()

    async def __aexit__(self, *exc_info) -> None:
        await self.close()

    @property
    def dropped(self) -> int:
        """Samples dropped so far: inbox overflow plus the subscriptions' drop-oldest."""
        inbox = self._inbox.dropped if self._inbox is not None else 0
        return inbox + self._dropped_by_closed + sum(s.dropped for s in self._subscriptions)

    # -- subscriptions -------------------------------------------------------------------

    def tracks(self, capacity: int | None = None, region: str | None = None) -> Subscription[TrackSet]:
        """Every :class:`~bintrack.bus_payloads.TrackSet` the base station (or the merge of the
        regions) publishes from now on; with ``region``, that region's base station's own
        (local track ids)."""
        key = self.keys.tracks() if region is None else self.keys.region_tracks(region)
        return self.subscribe(key, TrackSet, capacity)

    def estimates(self, node: str = "*", capacity: int | None = None) -> Subscription[LocalEstimate]:
        """Every :class:`~bintrack.bus_payloads.LocalEstimate` of peer agent ``node`` (``*``: all)."""
        return self.subscribe(self.keys.estimate(node), LocalEstimate, capacity)

    def transitions(self, sensor: str = "*", capacity: int | None = None) -> Subscription[Transition]:
        """Every :class:`~bintrack.bus_payloads.Transition` of ``sensor`` (``*``: all)."""
        return self.subscribe(self.keys.transition(sensor), Transition, capacity)

    def subscribe(self, key_expr: str, cls: type[M], capacity: int | None = None) -> Subscription[M]:
        """Messages of type ``cls`` on any key expression (e.g. ``c.keys.fusion_reports()``)."""
        subscription = Subscription(self, key_expr, cls, self.capacity if capacity is None else capacity)
        self._subscriptions.append(subscription)
        return subscription

    # -- queries -------------------------------------------------------------------------

    async def latest_tracks(self, timeout: float = 2.0) -> TrackSet | None:
        """The latest TrackSet from the ``tracks`` queryable, or None if nothing valid
        answered within ``timeout`` s. With several repliers, the one with the largest ``t``."""
        key = self.keys.tracks()
        best: TrackSet | None = None
        for sender, payload in await asyncio.to_thread(self._get, key, timeout):
            try:
                candidate = decode(TrackSet, payload)
            except MessageError as exc:
                self.bad.report(sender, exc.reason)
                continue
            if best is None or candidate.t > best.t:
                best = candidate
        return best

    async def alive(self, service: str = "*", timeout: float = 2.0) -> list[tuple[str, str]]:
        """``(service, instance)`` of every service instance holding its liveliness token
        under ``alive/`` (only ``service`` unless ``*``), sorted; replies waited ``timeout`` s."""
        key = self.keys.alive(service, "*")
        session = self._require_session()

        def ask() -> list[str]:
            return [str(r.ok.key_expr) for r in session.liveliness().get(key, timeout=timeout) if r.ok is not None]

        found = set()
        for token in await asyncio.to_thread(ask):
            parsed = parse_key(token)
            found.add((parsed.service, parsed.instance))
        return sorted(found)

    # -- internals -----------------------------------------------------------------------

    def _require_session(self) -> zenoh.Session:
        if self._session is None:
            raise RuntimeError("the client is not open (use `async with BintrackClient(...) as c:`)")
        return self._session

    def _declare_subscriber(self, key_expr: str, handler):
        session = self._require_session()
        return session.declare_subscriber(key_expr, self._inbox.callback(handler))

    def _forget(self, subscription: Subscription) -> None:
        if subscription in self._subscriptions:
            self._subscriptions.remove(subscription)
            self._dropped_by_closed += subscription.dropped

    def _get(self, key_expr: str, timeout: float) -> list[tuple[str, bytes]]:
        """(key, payload) of each successful reply to a get (blocking; runs in a thread)."""
        session = self._require_session()
        return [(str(r.ok.key_expr), r.ok.payload.to_bytes())
                for r in session.get(key_expr, timeout=timeout) if r.ok is not None]
