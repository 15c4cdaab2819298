"""Replay's run: the plan of :func:`~bintrack.live.replay_schedule.schedule` executed on the
bus, paced on the wall clock for ``--speed``, held at the :class:`~bintrack.live.replay_gate.ReplayGate`,
checkpointed at each tick, and resumed after a restart."""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable, Iterator

from bintrack.keys import Keys
from bintrack.live.checkpoint import ReplayCheckpoint
from bintrack.live.replay_gate import ReplayGate
from bintrack.live.replay_schedule import End, Gap, Pacer, Publish, Tick
from bintrack.live.replay_source import Put, ReplaySource
from bintrack.bus_payloads import Clock, EndOfStream
from bintrack.message_codec import RESENT, encode

PROGRESS_INTERVAL = 5.0  # s of wall clock between progress lines
YIELD_EVERY = 0.002  # s of wall clock between two turns given to the loop while publishing (waits give more)

log = logging.getLogger("bintrack")


class ReplayPlayer:
    """Plays ``plan`` (actions over ``source``) on ``keys`` with ``put(key, payload, attachment)``;
    ``save(checkpoint)`` keeps its position; ``stopping`` is set when replay stops."""

    def __init__(self, plan: Iterator, source: ReplaySource, gate: ReplayGate, keys: Keys, put: Put,
                 save: Callable[[ReplayCheckpoint], None], stopping: asyncio.Event, speed: float, loop: bool):
        self.plan = plan
        self.source = source
        self.gate = gate
        self.keys = keys
        self.put = put
        self.save = save
        self.stopping = stopping
        self.speed = speed
        self.loop = loop
        self.published = 0
        self.resume_after: float | None = None

    def resume(self, saved: ReplayCheckpoint) -> None:
        """After a restart: walk the plan up to the tick the previous instance checkpointed,
        publishing nothing but keeping the raw samples of the last ticks, so that ``recent``
        answers a restarted sensor agent at once, before the stack is complete again (the
        others wait for this replay's answer; it waits for them)."""
        self.resume_after, self.published = saved.tick, saved.published
        for action in self.plan:
            if isinstance(action, Tick):
                self._ticked(action.t, save=False)
                if action.t >= self.resume_after:
                    return
            elif isinstance(action, Publish):
                self.source.publish(action, None)

    def _send_again(self) -> int:
        """After a restart, before anything new: put the raw samples of the last ticks again,
        marked :data:`RESENT`. The killed instance checkpointed each tick once it had put it,
        but what it put last may still have been in its send path; every consumer has
        acknowledged the ticks before these, so nothing older can be missing. How many."""
        again = self.source.last_ticks()
        for key, payload in again:
            self.put(key, payload, RESENT)
        return len(again)

    def _ticked(self, t: float, save: bool = True) -> None:
        """After the tick at ``t`` (s): trim the source's memory and checkpoint the position."""
        self.source.ticked(t)
        self.gate.last_tick = t
        if save:
            self.save(ReplayCheckpoint(t, self.published))

    async def play(self, control: bytes) -> None:
        """Execute the plan: publish, tick and end as it says, paced, waiting at the gate."""
        self.gate.pacer = pacer = Pacer(self.speed)
        started = last_said = yielded_at = time.monotonic()
        skip_ack = False
        if self.resume_after is not None:  # a restart: what the previous instance published is done
            resent = self._send_again()
            log.info("replay: restarted; resuming after the tick at t=%g s (%d samples were published); sent "
                     "the %d raw samples of its last %d ticks again, and marks those up to its next tick "
                     "(receivers keep those they lack)", self.resume_after, self.published, resent,
                     len(self.source.recent_ticks))
            self.resume_after, skip_ack, again = None, True, RESENT
        else:
            again = None
        for action in self.plan:
            if isinstance(action, Gap):
                pacer.skip(action.to - action.t)
                log.info("replay: jumping over %g s of empty event time, from the tick at t=%g s to t=%g s "
                         "(longer than --max-gap)", action.to - action.t, action.t, action.to)
                continue
            quick = isinstance(action, Publish) and self.gate.clear()
            if not quick and not await self.gate.ready_for(action, skip_ack):  # (a sample owes no acknowledgement)
                break
            if not isinstance(action, Publish):
                skip_ack = False  # the progress owed to the previous instance went to it
            if isinstance(action, End):
                eos = encode(EndOfStream(t=action.t, awaited=sorted(self.gate.awaited()) or None))
                self.put(self.keys.eos(), eos, control)
                log.info("replay: end of stream at t=%g s after %d samples", action.t, self.published)
                if action.last:
                    await self.gate.linger(action.t, lambda: self.put(self.keys.eos(), eos, control))
                    return
                continue
            delay = pacer.delay(action.t, time.monotonic())
            if delay > 0:
                try:
                    await asyncio.wait_for(self.stopping.wait(), delay)
                except TimeoutError:
                    pass
            if self.stopping.is_set():
                break
            if isinstance(action, Tick):
                again = None
                tick = encode(Clock(t=action.t, sent=self.source.raw_published, sent_to=self.source.counts()))
                self.put(self.keys.clock(), tick, control)
                self.gate.tick_again = lambda payload=tick: self.put(self.keys.clock(), payload, control)
                self._ticked(action.t)
                if time.monotonic() - yielded_at >= YIELD_EVERY:
                    await asyncio.sleep(0)  # let signals and progress reports in
                    yielded_at = time.monotonic()
            else:
                self.source.publish(action, self.put, again)  # (the killed instance may have put it)
                self.published += 1
            now = time.monotonic()
            if now - last_said >= PROGRESS_INTERVAL:
                total = f"/{self.source.total}" if self.source.total and not self.loop else ""
                log.info("replay: %d%s samples published, event time %.3f s, %.0f samples/s",
                         self.published, total, action.t, self.published / (now - started))
                last_said = now
        log.info("replay: stopped after %d samples", self.published)


