"""Who is on the network: the one liveliness subscriber of a service.

Every service instance holds a token ``alive/<service>/<id>`` (a region's base station also
``region/<r>/alive``). A service follows them through one :class:`Presence`, with history (the
tokens declared before it came), and hands each change to the parts that care: the control
guard, the upstream watermark, end of stream, replay's flow control, the recorder, the merge.
A listener added later is told at once of the tokens present, as a subscriber with history
would be. An instance of a run started by ``up`` (``--stack ID``) counts only the tokens of the
run's own instances (ids ``ID-…``): any other is logged once and ignored, so that a token
declared by another client on an open bus can neither stall a watermark nor stop the run.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import zenoh

from bintrack.keys import Keys, ParsedKey, parse_key

log = logging.getLogger("bintrack")

PRESENCE_KINDS = frozenset({"alive", "region_alive"})

# listener(parsed key, present): present False when the token was withdrawn (or its holder lost)
Listener = Callable[[ParsedKey, bool], None]


class Presence:
    """The liveliness tokens of one network, followed by one subscriber (declared by
    :meth:`declare`), and the listeners to tell of each change, in the order they were added."""

    def __init__(self, keys: Keys, stack: str | None = None, who: str = "bintrack"):
        self.keys = keys
        self.stack = stack
        self.who = who
        self.ignored: set[str] = set()  # token keys of other instances, logged once
        self.present: dict[str, ParsedKey] = {}  # token key → its parse, while declared
        self._listeners: list[Listener] = []
        self._subscriber = None

    def listen(self, listener: Listener) -> None:
        """Tell ``listener`` of every token present now, then of each change."""
        self._listeners.append(listener)
        for parsed in list(self.present.values()):
            listener(parsed, True)

    def declare(self, session: zenoh.Session, deliver: Callable[[Callable[[zenoh.Sample], None]], Callable]) -> None:
        """Subscribe (once) to the network's tokens; ``deliver`` wraps the handler so that it runs
        on the service's loop (its inbox's callback)."""
        if self._subscriber is None:
            self._subscriber = session.liveliness().declare_subscriber(self.keys.all(), deliver(self.on_sample),
                                                                       history=True)

    def on_sample(self, sample: zenoh.Sample) -> None:
        """A token declared (PUT) or withdrawn (DELETE)."""
        key = str(sample.key_expr)
        try:
            parsed = parse_key(key)
        except ValueError:
            return
        if parsed.kind not in PRESENCE_KINDS or not self.of_the_run(key, parsed):
            return
        present = sample.kind == zenoh.SampleKind.PUT
        if present:
            self.present[key] = parsed
        else:
            self.present.pop(key, None)
        for listener in self._listeners:
            listener(parsed, present)

    def of_the_run(self, key: str, parsed: ParsedKey) -> bool:
        """Whether the token ``key`` is one of this run's instances (logs one that is not, once)."""
        if self.stack is None or parsed.kind != "alive" or parsed.instance.startswith(f"{self.stack}-"):
            return True
        if key not in self.ignored:
            self.ignored.add(key)
            log.warning("%s: ignoring the liveliness token %s: not one of run %s's instances", self.who, key,
                        self.stack)
        return False

    def holders(self, service: str) -> list[str]:
        """The instances of ``service`` whose tokens are present."""
        return [p.instance for p in self.present.values() if p.kind == "alive" and p.service == service]

    def undeclare(self) -> None:
        if self._subscriber is not None:
            self._subscriber.undeclare()
            self._subscriber = None


class OwnToken:
    """A service instance's own liveliness token ``key``, declared while it serves."""

    def __init__(self, key: str):
        self.key = key
        self._token = None

    def declare(self, session: zenoh.Session) -> None:
        self._token = session.liveliness().declare_token(self.key)

    def withdraw(self) -> bool:
        """Withdraw the token if declared; whether it was."""
        if self._token is None:
            return False
        self._token.undeclare()
        self._token = None
        return True


# The get ends when the router has answered, at once for a token that is not there; the timeout
# only bounds a router too busy to answer, which must not make a real sender's token look absent.
TOKEN_QUERY_TIMEOUT = 10.0  # s


def token_present(session: zenoh.Session, key: str) -> bool:
    """Whether a liveliness token on ``key`` is declared (a blocking get)."""
    return any(reply.ok is not None for reply in session.liveliness().get(key, timeout=TOKEN_QUERY_TIMEOUT))
