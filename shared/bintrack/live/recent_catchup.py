"""A sensor agent's catch-up from replay's ``control/recent`` answer (its restart, its router's
return, replay's return after a cut link): the hosted sensors' raw samples it lacks, and the
count of those replay published that it neither received nor could still be given."""

from __future__ import annotations

import math
from dataclasses import dataclass

from bintrack.bus_payloads import Clock, RawSample
from bintrack.live.sensor_hosting import HostedSensors
from bintrack.message_codec import MessageError, decode_view


@dataclass
class CatchUp:
    """What one ``recent`` answer gave: ``taken`` samples handled by hosted sensors, ``held``
    samples in it (all sensors'), the event time of the first, s, and ``published``, replay's
    count of raw samples so far (None if the answer did not say), and whether it was complete."""

    taken: int = 0
    held: int = 0
    first_held: float = math.inf
    published: int | None = None
    complete: bool = False

    def lost(self, published_by_tick: int | None, arrived: int) -> int | None:
        """Raw samples published after the tick whose count was ``published_by_tick`` that
        neither ``arrived`` (after that tick) nor were held: what arrived is a prefix of what
        was published since, what replay holds a suffix. None if a count is unknown."""
        if self.published is None or published_by_tick is None:
            return None
        return max(0, self.published - published_by_tick - arrived - self.held)


def take_recent(replies: list[bytes], hosts: HostedSensors, newer: bool) -> CatchUp:
    """Hand the hosted sensors' samples of ``replies`` (a ``recent`` answer, in order) to them:
    with ``newer`` only those later than the sensor's last sample (the others arrived), else
    also one at its last sample's time (a restart resumes at a tick)."""
    out = CatchUp()
    for payload in replies:
        try:
            raw = decode_view(RawSample, payload)
        except MessageError:
            try:
                out.published, out.complete = decode_view(Clock, payload).sent, True
            except MessageError:
                pass
            continue
        out.held += 1
        out.first_held = min(out.first_held, raw.t)
        hosted = hosts.sensors.get(raw.sensor)
        if hosted is not None and (raw.t > hosted.last_t or (not newer and raw.t == hosted.last_t)):
            hosted.handle(raw)
            out.taken += 1
    return out
