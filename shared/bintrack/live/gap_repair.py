"""How a transition consumer gets every transition once: ``seq`` gaps repaired from the
sensors' ``state`` queryables, transitions a sensor agent says it sent that never arrived
fetched the same way, restarted sensor agents followed, and duplicates dropped (DESIGN §3).
A region's base station, which hears only the transitions it takes, counts them per agent
instead (:class:`~bintrack.live.count_order.CountOrder`, DESIGN §11)."""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field

from bintrack.keys import Keys
from bintrack.live.count_order import CountOrder
from bintrack.live.sequence_checks import SequenceCheck, SourceCheck
from bintrack.bus_payloads import SensorState, Transition
from bintrack.message_codec import MessageError, decode

log = logging.getLogger("bintrack")


@dataclass
class IntakeState:
    """What a consumer knows of the transitions it took (kept in its checkpoint)."""

    sequence: SequenceCheck = field(default_factory=SequenceCheck)
    sources: SourceCheck = field(default_factory=SourceCheck)
    fetched: set[tuple[str | None, int | None]] = field(default_factory=set)  # fetched from state; may still arrive
    newest: dict[str, float] = field(default_factory=dict)  # event time of the newest transition taken, per sensor
    restarts: set[str | None] = field(default_factory=set)  # sources seen counting from 1 again (logged once)
    order: CountOrder | None = None  # a region's base station hearing its sensors only: their counts per agent


class GapRepair:
    """Admits each transition of ``sensors`` once, in any order, to ``take``; ``query(selector,
    timeout)`` asks the sensors' state queryables (blocking), ``report(key, reason)`` counts a
    bad or duplicate input."""

    def __init__(self, who: str, keys: Keys, sensors: set[str], take: Callable[[Transition], None],
                 query: Callable[[str, float], list[bytes]], report: Callable[[str, str], None],
                 state: IntakeState | None = None):
        self.who = who
        self.keys = keys
        self.sensors = sensors
        self._take = take
        self.query = query
        self.report = report
        self.state = state if state is not None else IntakeState()
        if not hasattr(self.state, "order"):  # a checkpoint from before regions were counted
            self.state.order = None
        self.unanswered: set[str] = set()  # agents whose sent transitions wait for their state's answer
        self.forgotten: dict[str, int] = {}  # agent → the count from which it no longer had them (logged)

    def receive(self, transition: Transition, key: str) -> None:
        """A transition that arrived on ``key``: taken, repaired after a gap, or dropped."""
        state = self.state
        if transition.sensor not in self.sensors:
            if state.order is None:
                state.sources.accept(transition)  # another region's sensor: its agent's count stays whole
            return
        self.follow_restart(transition)
        kind = state.sequence.classify(transition)
        if kind == "duplicate" or state.sources.seen(transition):
            if (transition.source, transition.source_seq) in state.fetched:
                state.fetched.discard((transition.source, transition.source_seq))  # fetched before it arrived
            else:
                self.report(key, f"duplicate: seq {transition.seq} seen already")
            return
        if kind == "gap":
            self.repair(transition)
        self.take(transition)

    def follow_restart(self, transition: Transition) -> None:
        """A restarted sensor agent counts ``seq`` (and, under the same id, ``source_seq``) from
        1 again: its transitions look old to the counters although they are newer in event
        time than anything taken of their sensor. Forget the old counts, so that they are taken
        (a genuine duplicate is never newer than what was taken)."""
        state = self.state
        old = state.sequence.classify(transition) == "duplicate" or state.sources.seen(transition)
        if not old or transition.t <= state.newest.get(transition.sensor, -math.inf):
            return
        state.sequence.last.pop(transition.sensor, None)
        if state.sources.seen(transition):
            state.sources.forget(transition.source)
            if state.order is not None:
                state.order.forget(transition.source)
        if transition.source not in state.restarts:
            state.restarts.add(transition.source)
            log.info("%s: %s counts its transitions from 1 again (a sensor agent restarted); following it",
                     self.who, transition.source or transition.sensor)

    def repair(self, transition: Transition) -> None:
        """Fetch the transitions lost before ``transition`` from its sensor's state queryable."""
        since = self.state.sequence.last.get(transition.sensor, 0)
        selector = f"{self.keys.state(transition.sensor)}?since={since}"
        if not self.fetch_missed(selector, before=transition):
            log.warning("%s: seq gap before %d of %s could not be repaired now (no state reply)%s", self.who,
                        transition.seq, transition.sensor,
                        "; asked again at its agent's next progress report" if transition.source else "")

    def agent_sent(self, source: str, sent: int) -> bool:
        """A sensor agent says it has sent ``sent`` transitions: fetch any that did not arrive.
        Whether the agent's count is settled: False while it has not answered (its queryable is
        not reachable yet, e.g. just after a router came back), so that its progress report
        must not move the watermark past transitions still to be fetched; the next report asks
        again. Transitions the agent answered without (past its memory) are logged as lost."""
        first = self.state.sources.first_missing(source, sent)
        if first is None:
            self.unanswered.discard(source)
            return True
        selector = f"{self.keys.state()}?source={source};after={first - 1}"
        if not self.fetch_missed(selector, upto=sent):
            self.held(source)
            return False
        if source in self.unanswered:
            self.unanswered.discard(source)
            log.info("%s: the transitions %s sent that did not arrive are fetched", self.who, source)
        still = self.state.sources.first_missing(source, sent)
        if still is not None and self.forgotten.get(source) != still:
            self.forgotten[source] = still
            log.warning("%s: %s sent transitions from its count %d on that were lost and are no longer in its "
                        "memory", self.who, source, still)
        return True

    def held(self, source: str) -> None:
        """``source``'s progress waits for transitions its state has not answered for in full (logged once)."""
        if source not in self.unanswered:
            self.unanswered.add(source)
            log.warning("%s: %s sent transitions that did not arrive and its state has not answered in full yet; "
                        "its progress is held until they are fetched", self.who, source)

    def settle(self, source: str, final: bool = False) -> list[float] | None:
        """A region's base station: the ticks (s) of ``source``'s reports whose transitions are
        all held, once; a report still short when the next came (or, ``final``, at the end of
        the stream) is a gap, fetched from the sensors' state first. None while ``source``'s
        state does not answer (its reports are held until it does)."""
        order = self.state.order
        short = order.short(source, final)
        force = False
        if short is not None:
            after = order.sources[source].settled
            if not self.fetch_missed(f"{self.keys.state()}?source={source};after={after}", upto=short.sent):
                self.held(source)
                return None
            self.unanswered.discard(source)
            force = True  # what the agent no longer had is lost: named below
        ticks = []
        for t, sent, missing in order.ready(source, force):
            self.state.sources.settle(source, sent)
            if missing and self.forgotten.get(source) != sent:
                self.forgotten[source] = sent
                log.warning("%s: %d transitions %s sent up to its count %d were lost and are no longer in its "
                            "memory", self.who, missing, source, sent)
            ticks.append(t)
        return ticks

    def taken(self, transition: Transition) -> bool:
        """Whether ``transition`` was taken already: by its agent's count where it carries one
        (exact in any order: a transition lost before a later one of its sensor that was taken
        is fetched afterwards), else by its sensor's ``seq``."""
        if transition.source is not None and transition.source_seq is not None:
            return self.state.sources.seen(transition)
        return self.state.sequence.classify(transition) == "duplicate"

    def fetch_since_received(self) -> str:
        """Fetch from the sensors' state every transition sent after the last one received in
        order: of each sensor (by ``seq``, from the lowest last seq of all sensors on; the
        duplicates are left out) and of each known sensor agent; says how many were taken, or
        that no sensor agent answered (then its progress reports ask again)."""
        before = len(self.state.fetched)
        since = min((self.state.sequence.last.get(sensor, 0) for sensor in self.sensors), default=0)
        answered = self.fetch_missed(f"{self.keys.state()}?since={since}")
        for source, received in self.state.sources.contiguous().items():
            self.fetch_missed(f"{self.keys.state()}?source={source};after={received}")
        if not answered:
            return ("no sensor agent answered yet (one restarting too?): the transitions sent since are fetched "
                    "as each reports its progress")
        return f"{len(self.state.fetched) - before} transitions sent since fetched from the sensors' state"

    def fetch_missed(self, selector: str, before: Transition | None = None, upto: int | None = None) -> bool:
        """Take the ``missed`` transitions of every state reply to ``selector``, oldest first:
        those before ``before`` (same sensor), or with source_seq ≤ ``upto``.

        The get blocks the loop on purpose: the fetched transitions must be taken before the
        next clock tick moves the watermark past them. A reply takes milliseconds; only a
        sensor agent that is gone costs the timeout. Whether it was answered: False if nobody
        replied, or an agent asked by source sent fewer replies than it said it would (its
        router went mid-answer: what is missing must not be named lost).
        """
        missed: list[Transition] = []
        replied = False
        answered: set[str] = set()
        expected = 0
        for payload in self.query(selector, 2.0):
            try:
                state = decode(SensorState, payload)
            except MessageError as exc:
                self.report(selector, exc.reason)
                continue
            replied = True
            answered.add(state.sensor)
            expected = max(expected, state.answers or 0)
            missed.extend(state.missed)
        if len(answered) < expected:
            # its router went while it answered: what did come is taken, the rest asked again
            log.warning("%s: %s answered for %d of its %d sensors (cut short); asked again", self.who, selector,
                        len(answered), expected)
            replied = False
        for transition in sorted(missed, key=lambda tr: (tr.sensor, tr.seq)):
            if before is not None and (transition.sensor != before.sensor or transition.seq >= before.seq):
                continue
            if upto is not None and transition.source_seq > upto:
                continue
            if self.state.order is not None and transition.sensor not in self.sensors:
                continue  # a sensor this region does not take (its agent answers for all it hosts)
            if not self.taken(transition):
                self.take(transition)
                self.state.fetched.add((transition.source, transition.source_seq))
        return replied

    def take(self, transition: Transition) -> None:
        """Count ``transition`` as received and hand it on if it is of one of ``sensors``."""
        state = self.state
        if transition.sensor not in self.sensors:
            if state.order is None:  # another region's sensor: received (its agent's count is whole), not tracked
                state.sources.accept(transition)
            return
        state.sources.accept(transition)
        if state.order is not None and transition.source is not None and transition.source_seq is not None:
            state.order.held(transition.source, transition.source_seq)
        state.sequence.accept(transition)
        state.newest[transition.sensor] = max(transition.t, state.newest.get(transition.sensor, -math.inf))
        self._take(transition)
