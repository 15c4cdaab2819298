"""Which raw samples a sensor agent hands to the sensors it hosts: the key and the payload name
the same sensor of the deployment, the value fits its kind, and a sample that a restarted
replay sent again is handled only if it is new to its sensor."""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable

from bintrack.bus_payloads import RawSample
from bintrack.formats import check_value
from bintrack.keys import Keys, parse_key
from bintrack.live.sensor_hosting import HostedSensors
from bintrack.message_codec import is_resent

log = logging.getLogger("bintrack")


class RawIntake:
    """Sensor agent ``name``'s intake of the deployment's raw samples (``sensors`` by id) into
    ``hosts``; ``report(key, reason)`` counts a refused sample."""

    def __init__(self, name: str, keys: Keys, sensors: dict, hosts: HostedSensors,
                 report: Callable[[str, str], None]):
        self.name = name
        self.sensors = sensors
        self.hosts = hosts
        self.report = report
        self.raw_keys = {sid: keys.raw(sid) for sid in sensors}
        self.resent = Counter()  # raw samples a restarted replay sent again: new (True) or already here (False)

    def take(self, key: str, raw: RawSample, attachment: bytes | None) -> None:
        """Hand ``raw``, heard on ``key`` with ``attachment``, to its hosted sensor if it is valid
        (else report it) and not another agent's sensor's."""
        expected = self.raw_keys.get(raw.sensor)
        if expected is None:
            if parse_key(key).sensor != raw.sensor:
                self.report(key, f"payload names sensor {raw.sensor!r}")
            else:
                self.report(key, f"unknown sensor id {raw.sensor!r}")
            return
        if key != expected:
            self.report(key, f"payload names sensor {raw.sensor!r}")
            return
        problem = check_value(self.sensors[raw.sensor], raw.value)
        if problem:
            self.report(key, problem)
            return
        hosted = self.hosts.sensors.get(raw.sensor)
        if hosted is None:  # another agent's sensor
            return
        if attachment is not None and is_resent(attachment):
            # sent again by a restarted replay: new only if later than what this sensor has
            if raw.t <= hosted.last_t:
                self.resent[False] += 1
                return
            self.resent[True] += 1
        hosted.handle(raw)

    def say_resent(self) -> None:
        """Log how many of the samples a restarted replay sent again were new, once per tick."""
        if self.resent:
            log.info("%s: of the raw samples a restarted replay sent again, %d were new and %d already handled",
                     self.name, self.resent[True], self.resent[False])
            self.resent.clear()
