"""End of stream: a service finishes once replay's ``control/eos`` has come and every live
instance of its upstream services has reported done."""

from __future__ import annotations

from collections.abc import Callable, Iterable

from bintrack.bus_payloads import EndOfStream as EndOfStreamMessage
from bintrack.keys import ParsedKey, parse_key


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

    def on_presence(self, parsed: ParsedKey, present: bool) -> None:
        """A token of ``alive/<service>/<id>`` declared or withdrawn (a Presence listener)."""
        if parsed.kind == "alive" and parsed.service in self.services:
            entry = (parsed.service, parsed.instance)
            (self.alive.add if present else self.alive.discard)(entry)

    def on_done(self, service: str, instance: str, t: float) -> None:
        if service in self.services:
            self.done[(service, instance)] = t

    @property
    def complete(self) -> bool:
        return all(entry in self.done for entry in self.alive)

    def owing(self) -> list[tuple[str, str]]:
        """The live instances that have not reported done, in order."""
        return sorted(entry for entry in self.alive if entry not in self.done)


class EndOfStream:
    """Calls ``finish(t)`` once, when the end of stream at ``t`` (s) has come and the upstream
    is done, then ``report_done(t)``; a ``finish`` that returns False is not done yet (a
    region's base station still waiting for transitions an agent counted) and calls
    :meth:`check` again."""

    def __init__(self, upstream: Iterable[str], finish: Callable[[float], None],
                 report_done: Callable[[float], None]):
        self.upstream = UpstreamDone(upstream)
        self.finish = finish
        self.report_done = report_done
        self.eos: float | None = None
        self.finished = False

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
                self.on_eos(message.t)

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

    def on_eos(self, t: float) -> None:
        if self.eos is None:
            self.eos = t
            self.check()

    def check(self) -> None:
        """Finish if the time has come; ``finish`` returning False holds it (it calls again)."""
        if self.eos is not None and not self.finished and self.upstream.complete:
            self.finished = True
            if self.finish(self.eos) is False:
                self.finished = False
                return
            self.report_done(self.eos)
