"""The base station of a tracker the peer agents run (the baselines, arc, sector): it orders the
peers' ``LocalEstimate``s by event time and publishes each as the single-target ``TrackSet``
(track 0) on ``tracks``.

Its watermark is the least of the clock tick − ``--lateness`` and the peer agents' released
watermarks; ties go by node id. Started by ``python -m bintrack.services.basestation --tracker
NAME`` for such a tracker; the ``tracks`` queryable returns the latest ``TrackSet``
(``tracks?after=T``: the recent ones after T). A restarted relay resumes from its checkpoint and
fetches the estimates published since from the peer agents' ``estimate?after=T`` queryables, at
once and from each peer agent again at its first progress report (a peer agent restarted with it
has then restored its history).
"""

from __future__ import annotations

from collections import deque
from operator import attrgetter

import zenoh

from bintrack.errors import CommandError
from bintrack.live.estimate_check import estimate_problem
from bintrack.keys import parse_key
from bintrack.live.checkpoint import RelayCheckpoint
from bintrack.live.service import log
from bintrack.live.track_history import TrackHistory
from bintrack.message_codec import MessageError, decode
from bintrack.live.transition_intake import TransitionConsumer
from bintrack.bus_payloads import Clock, LocalEstimate, Track, TrackSet
from bintrack.ordering import ReorderBuffer
from bintrack.pipeline import SINGLE_TARGET_TRACK

RECENT_PER_KEY = 64  # payloads remembered per node to drop the ones a restarted peer agent sends again


class EstimateRelay(TransitionConsumer):
    name = "basestation"

    def __init__(self, args):
        super().__init__(args)
        self.tracks = TrackHistory(self.keys.tracks())
        self.sensors: set[str] = set()
        self.estimates: ReorderBuffer[LocalEstimate] = ReorderBuffer(tiebreak=attrgetter("node"))
        self.recent_estimates: dict[str, deque[bytes]] = {}  # per node, its last estimates' payloads
        self.resumed: float | None = None  # the checkpoint's tick (s) after a restart
        self.fetched_from: set[str] = set()  # peer agents asked since the restart

    async def setup(self) -> None:
        deployment = await self.wait_for_deployment()
        if deployment is None:
            return
        if self.args.region is not None:
            raise CommandError(f"--region needs a base-station tracker (mcmcda), not {self.args.tracker}")
        self.serve(self.tracks.key, self.tracks.answer)
        self.sensors = set(deployment.by_id())
        saved = self.checkpoints.load(RelayCheckpoint)
        if saved is not None:
            self.estimates = saved.estimates
            self.recent_estimates = {node: deque(p, maxlen=RECENT_PER_KEY) for node, p in saved.recent.items()}
            self.tracks.restore(saved.latest, saved.history)
            self.resumed = saved.tick
        self.subscribe(self.keys.estimate(), self.on_estimate)
        self.subscribe(self.keys.clock(), self.on_clock)
        self.follow_upstream(("peer_agent",))
        self.watermark.released = self.estimates.released_until
        if saved is not None:
            log.info("%s: resumed at the clock tick t=%g s; %d estimates published since fetched from the peer "
                     "agents (again from each as it reports its progress)", self.name, saved.tick,
                     self.fetch_estimates())
        self.follow_end_of_stream(["peer_agent"], lambda t: self.emit(self.relayed(self.estimates.release_all())))

    def fetch_estimates(self) -> int:
        """Take the estimates not released yet that the peer agents' histories hold (their
        ``estimate?after=T`` queryables): those published while this relay was down. Blocks the
        loop on purpose, as the transitions' gap repair does: they must be in before the
        watermark moves past them. How many were new."""
        taken = 0
        released = self.estimates.released_until
        for payload in self.query(f"{self.keys.estimate()}?after={released!r}", 2.0):
            try:
                estimate = decode(LocalEstimate, payload)
            except MessageError as exc:
                self.bad.report(self.keys.estimate(), exc.reason)
                continue
            if estimate.t >= released:
                taken += self.take(estimate, payload, self.keys.estimate(estimate.node), fetched=True)
        return taken

    def on_upstream_progress(self, sample: zenoh.Sample) -> None:
        """After a restart, a peer agent's first progress report says it is back and caught up
        (its history restored): fetch from it before the watermark moves."""
        if self.resumed is not None:
            instance = parse_key(str(sample.key_expr)).instance
            if instance not in self.fetched_from:
                self.fetched_from.add(instance)
                taken = self.fetch_estimates()
                if taken:
                    log.info("%s: %d estimates fetched from peer_agent %s, back after the restart", self.name,
                             taken, instance)
        super().on_upstream_progress(sample)

    def on_estimate(self, sample: zenoh.Sample) -> None:
        estimate = self.decode(LocalEstimate, sample)
        if estimate is None:
            return
        self.take(estimate, sample.payload.to_bytes(), str(sample.key_expr))

    def take(self, estimate: LocalEstimate, payload: bytes, key: str, fetched: bool = False) -> bool:
        """Queue ``estimate`` (its ``payload``, from ``key``) unless it is bad, seen already or
        late; whether it was queued. A fetched one seen already is not counted as a duplicate."""
        problem = estimate_problem(estimate, key, self.keys, self.sensors, self.args.tracker)
        if problem:
            self.bad.report(key, problem)
            return False
        recent = self.recent_estimates.setdefault(estimate.node, deque(maxlen=RECENT_PER_KEY))
        if payload in recent:  # sent again by a peer agent that restarted from its checkpoint
            if not fetched:
                self.bad.report(key, f"duplicate: estimate at t={estimate.t} seen already")
            return False
        if self.estimates.push(estimate):
            recent.append(payload)
            return True
        self.bad.report(key, f"late: t={estimate.t} is behind the watermark {self.released:g} s "
                        f"(lateness {self.args.lateness} s)")
        return False

    def on_clock(self, sample: zenoh.Sample) -> None:
        tick = self.read(Clock, sample)
        if tick is None:
            return
        self.watermark.tick(tick.t)
        self.release(report=False)
        self.checkpoints.save_throttled(tick.t, lambda: RelayCheckpoint(
            tick.t, self.estimates, {node: list(p) for node, p in self.recent_estimates.items()},
            self.tracks.latest, list(self.tracks.recent)))
        self.report_released()

    def advance(self, watermark: float) -> list[TrackSet]:
        return self.relayed(self.estimates.release(watermark))

    def relayed(self, estimates: list[LocalEstimate]) -> list[TrackSet]:
        """Each estimate as the single-target track set."""
        return [TrackSet(t=e.t, tracker=self.args.tracker,
                         tracks=[Track(track=SINGLE_TARGET_TRACK, x=e.x, y=e.y, vx=e.vx, vy=e.vy)])
                for e in estimates]

    def emit(self, outputs: list[TrackSet]) -> None:
        for out in outputs:
            self.tracks.add(out)
            self.publish(self.tracks.key, out)
            self.sent += 1
