"""End of stream: a service finishes once replay's ``control/eos`` has come and every live
instance of its upstream services has reported done. An upstream service that had instances
and has none at the end (killed, restarting) is waited for, up to END_GRACE s: its restarted
instance still owes what it had not published."""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable, Iterable

from bintrack.bus_payloads import EndOfStream as EndOfStreamMessage
from bintrack.keys import ParsedKey, parse_key

END_GRACE = 30.0  # s of wall clock an upstream service gone at the end of stream is waited for

log = logging.getLogger("bintrack")


class UpstreamDone:
    """Which upstream service instances are alive and which reported done (end of stream).

    Feed it the liveliness tokens (:meth:`on_presence`) and the ``control/done/**`` reports
    (:meth:`on_done`); ``complete`` says every live instance of the watched services has
    reported done.
    """

    def __init__(self, services: Iterable[str]):
        self.services = set(services)
        self.alive: set[tuple[str, str]] = set()
        self.done: dict[tuple[str, str], float] = {}
        self.seen: set[str] = set()  # the watched services that had a live instance
        self.given_up: set[str] = set()  # gone ones no longer waited for
        self.gone_since: float | None = None  # wall clock (s) the wait for a gone one started

    def on_presence(self, parsed: ParsedKey, present: bool) -> None:
        """A token of ``alive/<service>/<id>`` declared or withdrawn (a Presence listener)."""
        if parsed.kind == "alive" and parsed.service in self.services:
            entry = (parsed.service, parsed.instance)
            (self.alive.add if present else self.alive.discard)(entry)
            if present:
                self.seen.add(parsed.service)
                self.given_up.discard(parsed.service)

    def on_done(self, service: str, instance: str, t: float) -> None:
        if service in self.services:
            self.done[(service, instance)] = t

    def gone(self) -> list[str]:
        """The watched services that had a live instance and have none now (not given up on)."""
        live = {service for service, _ in self.alive}
        return sorted(self.seen - live - self.given_up)

    def expect(self, services: Iterable[str]) -> None:
        """Replay awaits these services (its end of stream names them): wait for those watched
        here as for one seen live, even if none was (this instance restarted after the end)."""
        self.seen.update(self.services.intersection(services))

    def give_up(self, services: Iterable[str]) -> None:
        """Stop waiting for these gone services (until one of their instances is back)."""
        self.given_up.update(services)

    def wait_for_gone(self, name: str, eos: float, now: float) -> float | None:
        """The wait for the services gone at the end of stream at ``eos`` (s), seen from service
        ``name``: logs when it starts, and END_GRACE s of wall clock (``now``, monotonic s) later
        gives up on them with a line naming them. Returns the seconds left, None when none is gone."""
        gone = self.gone()
        if not gone:
            self.gone_since = None
            return None
        if self.gone_since is None:
            self.gone_since = now
            log.warning("%s: end of stream at t=%g s while %s has no live instance; waiting up to %g s for it to "
                        "come back and report done", name, eos, ", ".join(gone), END_GRACE)
        left = self.gone_since + END_GRACE - now
        if left > 0:
            return left
        log.warning("%s: %s did not come back within %g s of the end of stream; finishing without its done "
                    "report (what it had not published is missing)", name, ", ".join(gone), END_GRACE)
        self.give_up(gone)
        self.gone_since = None
        return None

    @property
    def complete(self) -> bool:
        return all(entry in self.done for entry in self.alive) and not self.gone()

    def owing(self) -> list[tuple[str, str]]:
        """The live instances that have not reported done, in order."""
        return sorted(entry for entry in self.alive if entry not in self.done)


class EndOfStream:
    """Calls ``finish(t)`` once, when the end of stream at ``t`` (s) has come and the upstream
    is done, then ``report_done(t)``; a ``finish`` that returns False is not done yet (a
    region's base station still waiting for transitions an agent counted) and calls
    :meth:`check` again."""

    def __init__(self, name: str, upstream: Iterable[str], finish: Callable[[float], None],
                 report_done: Callable[[float], None]):
        self.name = name
        self.upstream = UpstreamDone(upstream)
        self.finish = finish
        self.report_done = report_done
        self.eos: float | None = None
        self.finished = False
        self.grace: asyncio.TimerHandle | None = None  # the wait for a gone upstream service

    def follow(self, service) -> EndOfStream:
        """Hear ``service``'s (a :class:`~bintrack.live.service.Service`) liveliness tokens, done
        reports and ``control/eos``, a bad payload counted by ``service.decode``; returns self."""

        def on_done(sample) -> None:
            message = service.decode(EndOfStreamMessage, sample)
            if message is not None:
                parsed = parse_key(str(sample.key_expr))
                self.on_done(parsed.service, parsed.instance, message.t)

        def on_eos(sample) -> None:
            message = service.decode(EndOfStreamMessage, sample)
            if message is not None:
                self.on_eos(message.t, message.awaited or ())

        service.follow_presence(self.on_presence)
        service.subscribe(service.keys.done(), on_done)
        service.subscribe(service.keys.eos(), on_eos)
        return self

    def on_presence(self, parsed: ParsedKey, present: bool) -> None:
        self.upstream.on_presence(parsed, present)
        self.check()

    def on_done(self, service: str, instance: str, t: float) -> None:
        self.upstream.on_done(service, instance, t)
        self.check()

    def on_eos(self, t: float, awaited: Iterable[str] = ()) -> None:
        """Replay's end of stream at ``t`` (s), which names the ``awaited`` services. Said again
        after this service finished, it reports done again: replay repeats it for a downstream
        service that came back after the end, which waits for this report."""
        self.upstream.expect(awaited)
        if self.eos is None:
            self.eos = t
            self.check()
        elif self.finished and t == self.eos:
            self.report_done(t)

    def check(self) -> None:
        """Finish if the time has come; ``finish`` returning False holds it (it calls again).
        Called on the service's event loop."""
        if self.eos is None or self.finished:
            return
        left = self.upstream.wait_for_gone(self.name, self.eos, time.monotonic())
        if left is not None and self.grace is None:
            self.grace = asyncio.get_running_loop().call_later(left, self._grace_over)
        if self.upstream.complete:
            self.finished = True
            if self.finish(self.eos) is False:
                self.finished = False
                return
            self.report_done(self.eos)

    def _grace_over(self) -> None:
        self.grace = None
        self.check()
