"""A service's progress and done reports (flow control, keys beyond DESIGN §3, under ``control/``).

After each clock tick a service has processed it publishes ``control/progress/<service>/<id>``
(a ``Clock``); at end of stream, once its own upstream services are done, it publishes
``control/done/<service>/<id>`` (an ``EndOfStream``). Replay stays a bounded event-time window
ahead of the slowest service.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable

from bintrack.bus_payloads import Clock, EndOfStream
from bintrack.message_base import Message

ACK_TICKS = 8  # progress reports pending at most (replay's --max-ahead must be at least this to never wait) …
ACK_WAIT = 0.005  # … or s of wall clock since the last report, whichever comes first


class ProgressReports:
    """Sends one service instance's progress reports, a few ticks at a time when replay runs fast.

    ``publish(key, message)`` puts a message; ``is_open()`` says whether the session still is.
    """

    def __init__(self, progress_key: str, done_key: str, publish: Callable[[str, Message], None],
                 is_open: Callable[[], bool]):
        self.progress_key = progress_key
        self.done_key = done_key
        self._publish = publish
        self._is_open = is_open
        self.loop: asyncio.AbstractEventLoop | None = None  # set once the service runs
        self._pending: Clock | None = None  # a progress report not sent yet
        self._unreported = 0
        self._reported_at = -math.inf
        self._timer: asyncio.TimerHandle | None = None

    def report(self, t: float, sent: int | None = None, released: float | None = None,
               sent_to: dict[str, int] | None = None) -> None:
        """Report the clock tick ``t`` (s) handled (and, for a sensor agent, the transitions
        ``sent``, per region that takes them in ``sent_to``; for a tracker service, the
        watermark ``released``, s). Sent at once if
        ACK_WAIT s passed since the last report or ACK_TICKS reports are pending, else within
        ACK_WAIT s (the newest one): a report per tick at real time, one per few ticks when
        replay runs as fast as it can, and never a tick left unacknowledged."""
        self._pending = Clock(t=t, sent=sent, released=released, sent_to=sent_to)
        self._unreported += 1
        if self._unreported >= ACK_TICKS or time.monotonic() - self._reported_at >= ACK_WAIT:
            self.flush()
        elif self._timer is None:
            self._timer = self.loop.call_later(ACK_WAIT, self.flush)

    def flush(self) -> None:
        """Publish the pending progress report, if any."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self._pending is not None and self._is_open():
            self._publish(self.progress_key, self._pending)
        self._pending, self._unreported, self._reported_at = None, 0, time.monotonic()

    def done(self, t: float) -> None:
        """End of stream at ``t`` (s) handled: the last progress, then done."""
        self.flush()
        self._publish(self.done_key, EndOfStream(t=t))
