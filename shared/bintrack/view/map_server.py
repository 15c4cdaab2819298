"""The map's web server: aiohttp serving the page and one WebSocket per page.

A *source* gives each page a :class:`PageFeed` (and takes the page's commands): live, every
page shares one :class:`MapHub` fed from the bus; for a recording, each page has its own
player (:mod:`.recording_source`). The server sends a page JSON arrays of items
(:mod:`.map_messages`), first a snapshot of the whole picture, then each item as it comes.
A page that reads slower than items come is dropped to the latest state: its outbox holds at
most ``capacity`` items, and past that they are discarded and the next send is a fresh
snapshot instead, so a slow page never grows the server's memory.

Routes: ``/`` the page, ``/static/…`` its files (Leaflet vendored), ``/ws`` the WebSocket,
``/state.json`` the current snapshot (for scripts); every one behind :mod:`.map_access`.
"""

from __future__ import annotations

import asyncio
import json
import logging
import socket
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol
from urllib.parse import quote

from aiohttp import WSMsgType, web

from bintrack.view.map_access import MapAccess
from bintrack.view.map_messages import Item
from bintrack.view.map_socket import DEFAULT_BIND, DEFAULT_PORT, listening_socket  # noqa: F401 (the server's too)
from bintrack.view.map_state import MapState

STATIC = Path(__file__).resolve().parent / "static"
DEFAULT_PAGE_QUEUE = 1024      # items waiting for one page before it is dropped to the latest state

log = logging.getLogger("bintrack")


def dumps(value: Any) -> str:
    return json.dumps(value, separators=(",", ":"), allow_nan=False)


class PageFeed:
    """One page's outbox: items in order, at most ``capacity``; past that the queue is
    discarded (counted in ``dropped``) and the page is sent ``snapshot()`` instead."""

    def __init__(self, snapshot: Callable[[], Item], capacity: int = DEFAULT_PAGE_QUEUE):
        if capacity < 1:
            raise ValueError(f"a page queue needs capacity >= 1, got {capacity}")
        self.snapshot = snapshot
        self.capacity = capacity
        self.items: deque[Item] = deque()
        self.resync = True          # the first thing a page gets is the whole picture
        self.dropped = 0
        self.resyncs = 0
        self._ready = asyncio.Event()
        self._ready.set()
        self.closed = False

    def push(self, item: Item) -> None:
        if self.closed:
            return
        if self.resync:             # a snapshot is due anyway and will include it
            self.dropped += 1
            return
        if len(self.items) >= self.capacity:
            self.dropped += len(self.items)
            self.items.clear()
            self.resync = True
            self.resyncs += 1
        else:
            self.items.append(item)
        self._ready.set()

    def request_snapshot(self) -> None:
        """Send the whole picture next (after a seek, a new deployment)."""
        self.items.clear()
        self.resync = True
        self._ready.set()

    async def take(self) -> list[Item]:
        """What to send next (waits until there is something): a snapshot or the queued items."""
        while not (self.resync or self.items):
            self._ready.clear()
            await self._ready.wait()
        if self.resync:
            self.resync = False
            self.items.clear()
            return [self.snapshot()]
        batch = list(self.items)
        self.items.clear()
        return batch

    def close(self) -> None:
        self.closed = True
        self.items.clear()
        self._ready.set()


class Page(Protocol):
    """What a source gives each connected page."""

    feed: PageFeed

    async def command(self, message: dict) -> None: ...

    def close(self) -> None: ...


class Source(Protocol):
    async def open_page(self) -> Page: ...

    def snapshot(self) -> Item: ...


class MapHub:
    """The live picture shared by every page: items go into :class:`MapState` and to each
    page's feed; ``status`` (bus, services, rates) rides along in every snapshot."""

    def __init__(self, state: MapState, capacity: int = DEFAULT_PAGE_QUEUE):
        self.state = state
        self.capacity = capacity
        self.feeds: set[PageFeed] = set()
        self.status: Item = {"k": "status", "mode": "live", "router": None, "services": [], "rates": {},
                             "message": "waiting for the deployment"}
        self.on_page: Callable[[], Any] | None = None   # called when a page connects (live: query the bus)

    def publish(self, item: Item) -> bool:
        """Apply ``item`` and send it to every page; False if the state refused it."""
        if not self.state.apply(item):
            return False
        for feed in self.feeds:
            feed.push(item)
        return True

    def broadcast(self, item: Item) -> None:
        """Send ``item`` (status, deployment) to every page without keeping it in the state."""
        for feed in self.feeds:
            feed.push(item)

    def set_status(self, **fields) -> None:
        self.status = {**self.status, **fields}
        self.broadcast(self.status)

    def snapshot(self) -> Item:
        return {**self.state.snapshot(), "status": self.status}

    async def open_page(self) -> LivePage:
        if self.on_page is not None:
            await self.on_page()
        page = LivePage(self)
        self.feeds.add(page.feed)
        return page


class LivePage:
    def __init__(self, hub: MapHub):
        self.hub = hub
        self.feed = PageFeed(hub.snapshot, hub.capacity)

    async def command(self, message: dict) -> None:
        """A live page can only ask for the whole picture again (it fell behind)."""
        if message.get("cmd") == "snapshot":
            self.feed.request_snapshot()

    def close(self) -> None:
        self.feed.close()
        self.hub.feeds.discard(self.feed)


def make_app(source: Source, token: str | None = None) -> web.Application:
    """The aiohttp application serving ``source``'s pictures, behind the checks of
    :class:`~bintrack.view.map_access.MapAccess` (Host, Origin, and ``token`` if given)."""
    app = web.Application(middlewares=[MapAccess(token).middleware()])
    app["pages"] = set()

    async def index(request: web.Request) -> web.FileResponse:
        return web.FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-cache"})

    async def state(request: web.Request) -> web.Response:
        return web.Response(text=dumps(source.snapshot()), content_type="application/json")

    async def websocket(request: web.Request) -> web.WebSocketResponse:
        ws = web.WebSocketResponse(heartbeat=10.0)
        await ws.prepare(request)
        page = await source.open_page()
        app["pages"].add(page)

        async def send() -> None:
            while not ws.closed and not page.feed.closed:
                batch = await page.feed.take()
                if batch and not ws.closed:
                    await ws.send_str(dumps(batch))

        sender = asyncio.create_task(send())
        try:
            async for msg in ws:
                if msg.type == WSMsgType.TEXT:
                    try:
                        command = json.loads(msg.data)
                    except ValueError:
                        log.warning("view: a page sent something that is not JSON; ignored")
                        continue
                    if isinstance(command, dict):
                        await page.command(command)
                if sender.done():
                    break
        finally:
            page.close()
            app["pages"].discard(page)
            sender.cancel()
            try:
                await sender
            except (asyncio.CancelledError, ConnectionError):
                pass
            except Exception as exc:   # a send on a socket that went away
                log.debug("view: page sender ended: %s", exc)
        return ws

    async def close_pages(app: web.Application) -> None:
        for page in list(app["pages"]):
            page.close()

    app.router.add_get("/", index)
    app.router.add_get("/state.json", state)
    app.router.add_get("/ws", websocket)
    app.router.add_static("/static/", STATIC, show_index=False)
    app.on_shutdown.append(close_pages)
    return app


async def start_site(app: web.Application, sock: socket.socket) -> web.AppRunner:
    """Serve ``app`` on the listening socket ``sock`` (see :func:`listening_socket`)."""
    runner = web.AppRunner(app, handle_signals=False, access_log=None)
    await runner.setup()
    site = web.SockSite(runner, sock)
    try:
        await site.start()
    except OSError as exc:
        await runner.cleanup()
        raise OSError(f"cannot serve the map on {sock.getsockname()}: {exc.strerror or exc}") from None
    return runner


def served_line(service: str, bind: str, port: int, sock: socket.socket, token: str | None = None) -> str:
    """The one line that says where the map is served (and that ``port`` was taken, if so)."""
    served = sock.getsockname()[1]
    taken = f" (port {port} was taken)" if port not in (0, served) else ""
    every = f" (on every interface, {bind or '0.0.0.0'})" if bind in ("0.0.0.0", "", "::") else ""
    return f"{service}: map on {page_url(bind, served, token)}{every}{taken}"


def page_url(bind: str, port: int, token: str | None = None) -> str:
    """The URL a browser opens: on every interface (0.0.0.0, ::), this host's name; with the token."""
    host = socket.gethostname() if bind in ("0.0.0.0", "", "::") else (f"[{bind}]" if ":" in bind else bind)
    return f"http://{host}:{port}/" + (f"?token={quote(token, safe='')}" if token else "")
