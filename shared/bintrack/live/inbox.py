"""The bounded bridge from Zenoh's threads to a service's asyncio loop.

Zenoh callbacks run on Zenoh's threads; they must neither block nor call the Zenoh API
(DESIGN §3). The callback hands samples to the loop in batches (one
``loop.call_soon_threadsafe`` per wake-up) through an :class:`Inbox` that holds at most
``capacity`` samples: past that, a sample is dropped and counted instead of queued without
bound. A dropped transition shows as a ``seq`` gap, which the receiver repairs from the
sensor's ``state`` queryable.
"""

from __future__ import annotations

import asyncio
import threading
from collections import deque
from collections.abc import Callable
from typing import Any

from bintrack.live.session_options import DEFAULT_MAX_PAYLOAD

DEFAULT_INBOX = 65536


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

