"""The base station of a tracker the peer agents run (the baselines, arc, sector): it orders the
peers' ``LocalEstimate``s by event time and publishes each as the single-target ``TrackSet``
(track 0) on ``tracks``.

Its watermark is the least of the clock tick − ``--lateness`` and the peer agents' released
watermarks; ties go by node id. Started by ``python -m bintrack.services.basestation --tracker
NAME`` for such a tracker; the ``tracks`` queryable returns the latest ``TrackSet``
(``tracks?after=T``: the recent ones after T).
"""

from __future__ import annotations

from collections import deque
from operator import attrgetter

import zenoh

from bintrack.errors import CommandError
from bintrack.live.estimate_check import estimate_problem
from bintrack.live.track_history import TrackHistory
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

    async def setup(self) -> None:
        deployment = await self.wait_for_deployment()
        if deployment is None:
            return
        if self.args.region is not None:
            raise CommandError(f"--region needs a base-station tracker (mcmcda), not {self.args.tracker}")
        self.serve(self.tracks.key, self.tracks.answer)
        self.sensors = set(deployment.by_id())
        self.subscribe(self.keys.estimate(), self.on_estimate)
        self.subscribe(self.keys.clock(), self.on_clock)
        self.follow_upstream(("peer_agent",))
        self.follow_end_of_stream(["peer_agent"], lambda t: self.emit(self.relayed(self.estimates.release_all())))

    def on_estimate(self, sample: zenoh.Sample) -> None:
        estimate = self.decode(LocalEstimate, sample)
        if estimate is None:
            return
        key = str(sample.key_expr)
        problem = estimate_problem(estimate, key, self.keys, self.sensors, self.args.tracker)
        if problem:
            self.bad.report(key, problem)
            return
        recent = self.recent_estimates.setdefault(estimate.node, deque(maxlen=RECENT_PER_KEY))
        payload = sample.payload.to_bytes()
        if payload in recent:  # sent again by a peer agent that restarted from its checkpoint
            self.bad.report(key, f"duplicate: estimate at t={estimate.t} seen already")
            return
        if self.estimates.push(estimate):
            recent.append(payload)
        else:
            self.bad.report(key, f"late: t={estimate.t} is behind the watermark {self.released:g} s "
                            f"(lateness {self.args.lateness} s)")

    def on_clock(self, sample: zenoh.Sample) -> None:
        tick = self.read(Clock, sample)
        if tick is None:
            return
        self.watermark.tick(tick.t)
        self.release(report=False)
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
