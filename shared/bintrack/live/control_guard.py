"""Control-plane integrity: who may move a service's clock or end its stream.

``clock`` and ``control/eos`` drive every service: a clock tick moves the trackers' watermark,
an end of stream flushes and ends the run. :class:`ControlGuard` admits them only from a
sender that holds a replay's liveliness token (``alive/replay/<id>``, or the MQTT bridge's
``alive/mqtt_bridge/<id>``: the two sources of event time), named in the sample's
Zenoh attachment (:func:`control_attachment`), and admits ``control/progress/<service>/<id>``
and ``control/done/<service>/<id>`` only from a holder of ``alive/<service>/<id>`` (or a
former one: last words may arrive after the token's withdrawal). A clock tick
may step at most :data:`MAX_STEPS` times the step its replay announced (its clock period, or
the largest gap between a recording's ticks) past the last tick admitted (the first tick after
the source's token came back may be anywhere). Anything else is
rejected, counted and logged like a bad payload, naming the sender, and the run goes on.

Without access control on the router the attachment is a claim, not a proof: a client that
copies a live replay's id passes the token check (the step bound still holds it). Under the
secure profile (``deploy/secure/``) only the replay's certificate may put ``clock`` and
``control/eos`` at all, which makes the claim true.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache

import msgpack
import zenoh

from bintrack.keys import Keys, ParsedKey, parse_key
from bintrack.bus_payloads import Clock
from bintrack.message_codec import MessageError, decode_view

MAX_STEPS = 4.0  # a tick may be this many announced steps past the last one admitted
REPLAY = "replay"
CLOCK_SOURCES = (REPLAY, "mqtt_bridge")  # the services that drive event time (a replay, or the MQTT bridge)


def control_attachment(service: str, instance: str, step: float | None = None) -> bytes:
    """The attachment of a control message: the sender's ``<service>/<instance>`` (whose
    liveliness token it holds) and, for a replay's clock, its largest tick step ``step`` (s)."""
    body: dict[str, object] = {"sender": f"{service}/{instance}"}
    if step is not None:
        body["step"] = float(step)
    return msgpack.packb(body)


def claimed_sender(sample: zenoh.Sample) -> tuple[str | None, float | None]:
    """(``<service>/<instance>``, step s) that the sample's attachment claims; (None, None) if none."""
    if sample.attachment is None:
        return None, None
    return _claimed(sample.attachment.to_bytes())


@lru_cache(maxsize=256)  # a replay sends the same attachment with every tick
def _claimed(attachment: bytes) -> tuple[str | None, float | None]:
    try:
        body = msgpack.unpackb(attachment)
        sender, step = body.get("sender"), body.get("step")
    except (ValueError, AttributeError, msgpack.UnpackException):
        return None, None
    if not isinstance(sender, str) or sender.count("/") != 1:
        return None, None
    if not isinstance(step, (int, float)) or not 0 < step < float("inf"):
        step = None
    return sender, step


@dataclass
class ControlGuard:
    """Admits or rejects the control samples a service receives (see the module docstring).

    ``report(sender, reason)`` counts and logs a rejection (the service's bad-input
    accounting); ``lookup(key)`` is a blocking liveliness get, used when a sender's token has
    not been seen yet (its declaration and its first message travel on different paths).
    """

    keys: Keys
    report: Callable[[str, str], None]
    lookup: Callable[[str], bool]
    alive: set[str] = field(default_factory=set)
    departed: set[str] = field(default_factory=set)
    last_tick: float | None = None
    steps: dict[str, float] = field(default_factory=dict)
    rejected: int = 0

    @property
    def lead(self) -> float:
        """The event time (s) the clock sources announced may be in flight ahead of what their
        consumers acknowledged (a replay's ``--max-ahead`` clock periods); 0 before any tick."""
        return max(self.steps.values(), default=0.0)

    def on_presence(self, parsed: ParsedKey, present: bool) -> None:
        """Follow the ``alive/**`` tokens (a :class:`~bintrack.live.presence.Presence` listener)."""
        if parsed.kind == "alive":
            who = f"{parsed.service}/{parsed.instance}"
            if present:
                if who in self.departed and parsed.service in CLOCK_SOURCES:
                    # its source came back after it was out of reach (a cut link): event time may
                    # have gone on meanwhile (replay --no-hold, sensors in the field), so its next
                    # tick starts afresh rather than being taken for a jump
                    self.last_tick = None
                self.alive.add(who)
            elif who in self.alive:
                self.alive.discard(who)
                self.departed.add(who)

    def holds_token(self, who: str) -> bool:
        """Whether ``who`` holds its liveliness token, or held it: a service's last words (its
        done, a replay's end of stream) may arrive after its token's withdrawal."""
        if who in self.alive or who in self.departed:
            return True
        service, instance = who.split("/")
        if self.lookup(self.keys.alive(service, instance)):
            self.alive.add(who)
            return True
        return False

    def admit(self, sample: zenoh.Sample) -> bool:
        """True for a sample to hand on: any non-control sample, and control from its holder."""
        key = str(sample.key_expr)
        try:
            kind = parse_key(key).kind
        except ValueError:
            return True
        if kind in ("clock", "eos"):
            return self._from_replay(sample, kind)
        if kind in ("progress", "done"):
            parsed = parse_key(key)
            who = f"{parsed.service}/{parsed.instance}"
            if not self.holds_token(who):
                return self._reject(key, f"forged control: {kind} of {who}, which holds no liveliness token")
        return True

    def _from_replay(self, sample: zenoh.Sample, kind: str) -> bool:
        key = str(sample.key_expr)
        sender, step = claimed_sender(sample)
        if sender is None:
            return self._reject(f"{key} (no sender named)",
                                f"forged control: {kind} from an anonymous sender, not a replay's")
        if sender.split("/")[0] not in CLOCK_SOURCES or not self.holds_token(sender):
            return self._reject(f"{key} from {sender}",
                                f"forged control: {kind} from {sender}, which holds no {self.keys.alive(REPLAY)} token")
        if kind == "eos":
            return True
        try:
            t = decode_view(Clock, sample.payload.to_bytes()).t
        except MessageError:
            return True  # the handler reports the bad payload itself
        bound = self.steps.setdefault(sender, step) if step is not None else self.steps.get(sender)
        if self.last_tick is not None and bound is not None and t - self.last_tick > MAX_STEPS * bound:
            return self._reject(f"{key} from {sender}",
                                f"clock jump: t={t:g} s after t={self.last_tick:g} s, more than {MAX_STEPS:g} "
                                f"steps of {bound:g} s")
        self.last_tick = t if self.last_tick is None else max(self.last_tick, t)
        return True

    def _reject(self, sender: str, reason: str) -> bool:
        self.rejected += 1
        self.report(sender, reason)
        return False
