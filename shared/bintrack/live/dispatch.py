"""A service's one subscriber and the routing of its samples to handlers.

A service has one Zenoh subscriber, on its listen key (its whole network unless it narrows
it), and routes samples to handlers itself: Zenoh delivers one subscriber's samples in the
order each publisher sent them, but calls different subscribers from different threads, so
separate subscribers could see a publisher's messages on two keys swapped. A region's sensor
agent and base station narrow it to several listen keys (:meth:`Dispatch.narrow`: their
sensors' keys, the clock, the control keys), a subscriber each, so that a router forwards them
their region's part of the network only; they order by counts instead (DESIGN §11). Control samples
(clock, end of stream, progress, done) pass the :class:`~bintrack.live.control_guard.ControlGuard`
first. The subscriber hears other sessions only (its own puts are not delivered back to it).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable

import zenoh

from bintrack.keys import parse_key
from bintrack.live.control_guard import ControlGuard

ROUTE_CACHE = 65536  # distinct keys whose handlers are remembered (a bound against key floods)
GUARDED_KINDS = frozenset({"clock", "eos", "progress", "done"})  # what the control guard checks

Handler = Callable[[zenoh.Sample], None]


class Dispatch:
    """Routes the samples of one subscriber on ``listen_key`` to the handlers of the key
    expressions that include their keys, control samples only once ``guard`` admits them."""

    def __init__(self, listen_key: str, guard: ControlGuard):
        self.listen_keys = [listen_key]
        self.guard = guard
        self._listen = [zenoh.KeyExpr(listen_key)]
        self._routes: list[tuple[zenoh.KeyExpr, Handler]] = []
        self._cache: dict[str, tuple[bool, tuple[Handler, ...], str]] = {}
        self.heard: Counter = Counter()  # narrowed: samples routed, by key kind
        self.sensors_heard: dict[str, set[str]] | None = None  # narrowed: kind → the sensors heard on it

    def add(self, key_expr: str, handler: Handler) -> bool:
        """Route the samples whose keys ``key_expr`` includes to ``handler``; True for the first
        route (the caller then declares the subscriber, with :meth:`route` as its handler)."""
        pattern = zenoh.KeyExpr(key_expr)
        if not any(listen.intersects(pattern) for listen in self._listen):
            raise ValueError(f"{key_expr} is outside this service's subscriptions {', '.join(self.listen_keys)}")
        self._routes.append((pattern, handler))
        self._cache.clear()
        return len(self._routes) == 1

    def narrow(self, listen_keys: list[str]) -> None:
        """Listen on ``listen_keys`` (a subscriber each) instead of the one listen key; before
        the first route."""
        if self._routes:
            raise RuntimeError("narrow the subscriptions before the first route")
        self.listen_keys = list(listen_keys)
        self._listen = [zenoh.KeyExpr(key) for key in listen_keys]
        self.sensors_heard = {}

    def route(self, sample: zenoh.Sample) -> None:
        """Hand ``sample`` to its handlers (on the service's loop)."""
        key = str(sample.key_expr)
        entry = self._cache.get(key)
        if entry is None:
            entry = self._entry(key)
        guarded, handlers, kind = entry
        if guarded and not self.guard.admit(sample):  # clock and control/* only from their token holders
            return
        for handler in handlers:
            handler(sample)

    def route_counted(self, sample: zenoh.Sample) -> None:
        """:meth:`route`, counting what was heard (a narrowed service's, for :meth:`summary`)."""
        key = str(sample.key_expr)
        entry = self._cache.get(key)
        self.heard[entry[2] if entry is not None else self._entry(key)[2]] += 1
        self.route(sample)

    def _entry(self, key: str) -> tuple[bool, tuple[Handler, ...], str]:
        """(whether the control guard must see it, the handlers, the key's kind) of a concrete
        key, kept per key (the keys of a network are few: no key-expression matching per sample)."""
        expr = zenoh.KeyExpr(key)
        handlers = tuple(handler for pattern, handler in self._routes if pattern.includes(expr))
        try:
            parsed = parse_key(key)
        except ValueError:
            parsed = None
        kind = "other" if parsed is None else parsed.kind
        if self.sensors_heard is not None and parsed is not None and parsed.sensor is not None:
            self.sensors_heard.setdefault(kind, set()).add(parsed.sensor)  # (narrowed: known keys only)
        if len(self._cache) >= ROUTE_CACHE:
            self._cache.clear()
        entry = self._cache[key] = (kind in GUARDED_KINDS, handlers, kind)
        return entry

    def summary(self) -> str:
        """What was heard: samples by kind, and (narrowed) the sensors heard on each kind of key."""
        text = f"heard {sum(self.heard.values())} samples {dict(sorted(self.heard.items()))}"
        for kind, sensors in sorted((self.sensors_heard or {}).items()):
            text += f"; {kind} of {len(sensors)} sensors: {' '.join(sorted(sensors))}"
        return text
