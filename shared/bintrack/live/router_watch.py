"""A service's watch on its router: the loss and return of the router, from Zenoh's transport
events. While it is lost the service's liveliness token is withdrawn, so replay holds its
clock; once it is back the service fetches what it missed and declares its token again."""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Awaitable, Callable

import zenoh

log = logging.getLogger("bintrack")


class RouterWatch:
    """Follows the routers of one session. ``on_lost()`` runs when the last one goes (after
    ``withdraw()``); ``on_back()`` (a coroutine) when one is back, then ``redeclare()``."""

    def __init__(self, who: str, withdraw: Callable[[], bool], redeclare: Callable[[], None],
                 on_lost: Callable[[], None], on_back: Callable[[], Awaitable[None]],
                 stopping: Callable[[], bool]):
        self.who = who
        self.withdraw = withdraw
        self.redeclare = redeclare
        self.on_lost = on_lost
        self.on_back = on_back
        self.stopping = stopping
        self.routers: set[str] = set()  # the routers this session is connected to
        self.lost_at: float | None = None  # monotonic time the last router went, while none is back
        self.withdrawn = False  # the token was withdrawn at a loss and is not declared again yet

    def declare(self, session: zenoh.Session, loop: asyncio.AbstractEventLoop) -> object:
        """Listen to the session's transport events; returns the listener (to undeclare)."""
        self.routers = {str(zid) for zid in session.info.routers_zid()}

        def on_event(event) -> None:  # a Zenoh thread: hand over to the loop, nothing else
            if str(event.transport.whatami).lower() == "router":
                try:
                    loop.call_soon_threadsafe(self.on_event, event.kind == zenoh.SampleKind.PUT,
                                              str(event.transport.zid))
                except RuntimeError:  # loop closed during shutdown
                    pass

        return session.info.declare_transport_events_listener(on_event, history=False)

    def on_event(self, connected: bool, zid: str) -> None:
        """A router connected or disconnected (on the loop)."""
        if self.stopping():
            return
        if connected:
            self.routers.add(zid)
            if self.lost_at is not None:
                log.warning("%s: router %s reached again after %.1f s", self.who, zid[:8],
                            time.monotonic() - self.lost_at)
                self.lost_at = None
                asyncio.ensure_future(self._recover())
            return
        self.routers.discard(zid)
        if self.routers or self.lost_at is not None:
            return
        self.lost_at = time.monotonic()
        log.warning("%s: lost its router %s; waiting for it to come back", self.who, zid[:8])
        if self.withdraw():
            self.withdrawn = True
        self.on_lost()

    async def _recover(self) -> None:
        await self.on_back()
        if self.withdrawn and self.lost_at is None and not self.stopping():
            self.withdrawn = False
            self.redeclare()
