"""The payloads on the bus (DESIGN §3–4), one pydantic model each: raw samples, transitions,
estimates, position reports, track sets, line-object and velocity estimates, truth, the clock
and end of stream."""

from __future__ import annotations

from typing import ClassVar

from pydantic import Field, NonNegativeInt, model_serializer

from bintrack.message_base import FrozenModel, Message, Seconds


class RawSample(Message):
    """One sample of one sensor as the hardware (or replay) reports it."""

    t: Seconds
    sensor: str = Field(description="sensor id")
    value: int = Field(description="disk 0/1; sector 0..s-1 or -1; motion +1/-1; line 1")


class Transition(Message):
    """A change of a sensor's status (papers 000, 001): sent only when the status changes."""

    t: Seconds
    sensor: str = Field(description="sensor id")
    value: int = Field(description="new status")
    previous: int = Field(description="status before the change")
    seq: int = Field(ge=1, description="per-sensor sequence number, 1 for the first transition")
    source: str | None = Field(None, description="id of the sensor-agent instance that published it")
    source_seq: int | None = Field(None, ge=1, description="that instance's count of transitions, 1 for its first")


class SensorState(Message):
    """Reply of a sensor's ``state`` queryable: its current status and last ``seq``, and the
    recent transitions after the ``since`` seq the query asked for (to repair a gap)."""

    t: Seconds
    sensor: str
    value: int
    seq: int = Field(ge=0, description="seq of the last transition, 0 if none yet")
    missed: list[Transition] = Field(default_factory=list, description="transitions after the asked seq, oldest first")
    answers: int | None = Field(None, ge=1, description="to a query by ``source``: how many replies its agent sends, one "
                                "per sensor it hosts, so that an asker can tell an answer cut short (its router went)")


class LocalEstimate(Message):
    """A node's estimate of the target at one of its transitions (peer agents, single target)."""

    t: Seconds
    node: str = Field(description="id of the estimating node")
    tracker: str = Field(description="tracker name")
    x: float = Field(description="position, deployment units")
    y: float = Field(description="position, deployment units")
    vx: float | None = Field(None, description="velocity, units/s")
    vy: float | None = Field(None, description="velocity, units/s")
    arc: float | None = Field(None, ge=0, description="central angle of the final arc, rad (arc/sector trackers)")
    weight: float | None = Field(None, ge=0, description="trajectory-fit weight (paper 001 eq. 2 or 4)")


class PositionReport(FrozenModel):
    x: float = Field(description="position, deployment units")
    y: float = Field(description="position, deployment units")
    cov: tuple[tuple[float, float], tuple[float, float]] = Field(
        description="2×2 position covariance, units²"
    )
    weight: float = Field(1.0, ge=0, description="the report's evidence: its cluster's summed cell likelihood "
                          "(clustering fusion) or its gain, nats of eq. 4 (fitted fusion); 0 for a shared copy")
    shared: bool = Field(False, description="a copy of another report, for a second target that a track "
                         "expects there but whose detections are unresolved from that report's")


class PositionReports(Message):
    """One scan of fused position reports (paper 004 §III)."""

    t: Seconds
    reports: list[PositionReport]


class Track(FrozenModel):
    track: int = Field(ge=0, description="track identity, persistent across scans")
    x: float = Field(description="position, deployment units")
    y: float = Field(description="position, deployment units")
    vx: float | None = Field(None, description="velocity, units/s")
    vy: float | None = Field(None, description="velocity, units/s")
    region: str | None = Field(None, description="merged picture: the region whose base station tracks it")
    stale: bool = Field(False, description="merged picture: its region's base station is gone; the last "
                        "position it gave, not updated")


class TrackSet(Message):
    """The tracks at one scan; also what the ``tracks`` queryable returns."""

    t: Seconds
    tracker: str
    tracks: list[Track]


class LineObjectEstimate(Message):
    """One object's straight pass through a line-sensor region (paper 003)."""

    object: int = Field(ge=1, description="pass number, from 1 in time order")
    t_first: Seconds
    t_last: Seconds
    entry_x: float
    entry_y: float
    exit_x: float
    exit_y: float
    vx: float = Field(description="velocity, units/s")
    vy: float = Field(description="velocity, units/s")
    entry_sd: float | None = Field(default=None, ge=0, description="standard deviation of the entry point, units "
                                   "(√ trace of its covariance; None if unknown)")
    exit_sd: float | None = Field(default=None, ge=0, description="standard deviation of the exit point, units "
                                  "(√ trace of its covariance; None if unknown)")
    revision: int | None = Field(default=None, ge=1, description="1, 2, … for a revised estimate of a pass already "
                                 "published (the latest counts); None for the first estimate")


class VelocityEstimate(Message):
    """Velocity (and optionally position) from closer/farther sensors (paper 002)."""

    t: Seconds
    method: str = Field(description="velocity-plane, svm, ppr or motion-rw")
    vx: float = Field(description="units/s")
    vy: float = Field(description="units/s")
    x: float | None = None
    y: float | None = None


class TruthSample(Message):
    """One row of a dataset's truth.csv, replayed in event time beside the events (optional
    ``truth`` key): where target ``target`` really was at ``t``."""

    t: Seconds
    target: str = Field(description="target id as in truth.csv")
    x: float = Field(description="position, deployment units")
    y: float = Field(description="position, deployment units")


class _AddedLater(Message):
    """A message with an optional field ``added_later``, left out when absent: its bytes and
    JSON stay what they were before the field was added."""

    added_later: ClassVar[str]

    @model_serializer(mode="wrap")
    def _later_field_only_when_given(self, handler):
        data = handler(self)
        if getattr(self, self.added_later) is None:
            data.pop(self.added_later, None)
        return data


class Clock(_AddedLater):
    """Event time advances even when no sensor reports. Also a service's progress report."""

    added_later = "sent_to"
    t: Seconds
    sent: int | None = Field(None, ge=0, description="what the sender has sent so far: in replay's (or the MQTT "
                             "bridge's) tick its raw samples; in a progress report a sensor agent's transitions, a "
                             "peer agent's estimates, a base station's or the merge's track sets")
    released: float | None = Field(None, description="in a tracker service's progress report: its watermark, s — "
                                   "every output of an event time before it has been published")
    sent_to: dict[str, NonNegativeInt] | None = Field(
        None, description="the part of ``sent`` each region takes, by region name (a deployment with regions): in "
        "replay's tick the raw samples of the sensors placed in the region; in a sensor agent's progress report its "
        "transitions of the sensors the region's base station takes (border band included). A receiver that "
        "subscribes to its region's keys only holds a report until it has that many (DESIGN §11)")


class EndOfStream(_AddedLater):
    """The replay has ended: flush and emit final results. Also a service's done report."""

    added_later = "awaited"
    t: Seconds
    awaited: list[str] | None = Field(
        None, description="in replay's end of stream: the services it waits for (its --wait-for), each of whose "
        "instances reports done. A service waits for those upstream of it to be live and done, also one it has not "
        "seen live (it restarted after the end went out)")
