"""Key expressions of DESIGN §3: build them for a network and parse them back.

Every key is ``bintrack/<net>/<suffix>``; ``<net>`` is the deployment name.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

from bintrack.messages import check_sensor_id

ROOT = "bintrack"

# kind -> (suffix before the id, suffix after the id); None where the key has no id part.
_PER_SENSOR = {
    "raw": ("raw", None),
    "transition": ("sensor", "transition"),
    "state": ("sensor", "state"),
    "estimate": ("peer", "estimate"),
}
_FIXED = {
    "fusion/reports": "fusion_reports",
    "tracks": "tracks",
    "laser/objects": "laser_objects",
    "motion/velocity": "motion_velocity",
    "truth": "truth",
    "deployment": "deployment",
    "clock": "clock",
    "control/eos": "eos",
}


def _chunk(value: str, what: str) -> str:
    if not value or any(c in value for c in "/*$?#") or value.strip() != value:
        raise ValueError(f"{what} {value!r} cannot be a key-expression chunk")
    return value


@dataclass(frozen=True)
class Keys:
    """The key expressions of one network (``net``)."""

    net: str = "default"

    def __post_init__(self):
        _chunk(self.net, "network name")

    @property
    def prefix(self) -> str:
        return f"{ROOT}/{self.net}"

    def all(self) -> str:
        """Everything of this network: what the recorder subscribes to."""
        return f"{self.prefix}/**"

    def raw(self, sensor: str = "*") -> str:
        return f"{self.prefix}/raw/{self._sensor(sensor)}"

    def transition(self, sensor: str = "*") -> str:
        return f"{self.prefix}/sensor/{self._sensor(sensor)}/transition"

    def state(self, sensor: str = "*") -> str:
        return f"{self.prefix}/sensor/{self._sensor(sensor)}/state"

    def estimate(self, sensor: str = "*") -> str:
        return f"{self.prefix}/peer/{self._sensor(sensor)}/estimate"

    def fusion_reports(self) -> str:
        return f"{self.prefix}/fusion/reports"

    def tracks(self) -> str:
        return f"{self.prefix}/tracks"

    def region_reports(self, region: str = "*") -> str:
        """A region's base station: its ``PositionReports`` (DESIGN §9)."""
        return f"{self.prefix}/region/{self._region(region)}/fusion/reports"

    def region_tracks(self, region: str = "*") -> str:
        """A region's base station: its ``TrackSet`` (local ids); the merge makes ``tracks`` of them."""
        return f"{self.prefix}/region/{self._region(region)}/tracks"

    def region_progress(self, region: str = "*") -> str:
        """A region's base station: a ``Clock`` after each tick, the event time up to which its
        tracks are final (every scan at or before it was published)."""
        return f"{self.prefix}/region/{self._region(region)}/progress"

    def region_alive(self, region: str = "*") -> str:
        """Liveliness token of a region's base station (one per region)."""
        return f"{self.prefix}/region/{self._region(region)}/alive"

    def laser_objects(self) -> str:
        return f"{self.prefix}/laser/objects"

    def motion_velocity(self) -> str:
        return f"{self.prefix}/motion/velocity"

    def truth(self) -> str:
        """Replay of a dataset with truth.csv: where the targets really are (``TruthSample``)."""
        return f"{self.prefix}/truth"

    def deployment(self) -> str:
        return f"{self.prefix}/deployment"

    def clock(self) -> str:
        return f"{self.prefix}/clock"

    def eos(self) -> str:
        return f"{self.prefix}/control/eos"

    def recent(self) -> str:
        """Replay's queryable of the raw samples it published since a clock tick (``?after=T``),
        for a sensor agent that restarts from its checkpoint."""
        return f"{self.prefix}/control/recent"

    def alive(self, service: str = "*", instance: str = "*") -> str:
        """Liveliness token key of a service instance (``*`` for any)."""
        return f"{self.prefix}/alive/{self._service(service, instance)}"

    def progress(self, service: str = "*", instance: str = "*") -> str:
        """Flow control: the event time (``Clock``) a service instance has processed."""
        return f"{self.prefix}/control/progress/{self._service(service, instance)}"

    def done(self, service: str = "*", instance: str = "*") -> str:
        """Flow control: a service instance has processed the end of stream (``EndOfStream``)."""
        return f"{self.prefix}/control/done/{self._service(service, instance)}"

    @staticmethod
    def _service(service: str, instance: str) -> str:
        service = service if service == "*" else _chunk(service, "service name")
        instance = instance if instance == "*" else _chunk(instance, "instance id")
        return f"{service}/{instance}"

    @staticmethod
    def _region(region: str) -> str:
        return region if region == "*" else _chunk(region, "region name")

    @staticmethod
    def _sensor(sensor: str) -> str:
        return sensor if sensor == "*" else check_sensor_id(sensor)


@dataclass(frozen=True)
class ParsedKey:
    """What a concrete key names: ``kind`` is one of raw, transition, state, estimate,
    fusion_reports, tracks, laser_objects, motion_velocity, truth, deployment, clock, eos, alive,
    progress, done (the last two are flow control, beyond DESIGN §3), and per region (``region``)
    region_reports, region_tracks, region_progress, region_alive."""

    net: str
    kind: str
    sensor: str | None = None
    service: str | None = None
    instance: str | None = None
    region: str | None = None


_PER_REGION = {"fusion/reports": "region_reports", "tracks": "region_tracks", "progress": "region_progress",
               "alive": "region_alive"}


def parse_key(key: str) -> ParsedKey:
    """Parse a concrete bintrack key; raises ValueError for anything else."""
    return _parse_key(str(key))


@lru_cache(maxsize=65536)  # a network has few keys; parsed once each (a bound against key floods)
def _parse_key(key: str) -> ParsedKey:
    parts = key.split("/")
    if len(parts) < 3 or parts[0] != ROOT or not parts[1]:
        raise ValueError(f"not a bintrack key: {key!r}")
    net, rest = parts[1], parts[2:]
    suffix = "/".join(rest)
    if suffix in _FIXED:
        return ParsedKey(net, _FIXED[suffix])
    if len(rest) == 2 and rest[0] == "raw" and rest[1]:
        return ParsedKey(net, "raw", sensor=rest[1])
    if len(rest) == 3 and rest[1]:
        for kind, (head, tail) in _PER_SENSOR.items():
            if rest[0] == head and rest[2] == tail:
                return ParsedKey(net, kind, sensor=rest[1])
    if len(rest) >= 3 and rest[0] == "region" and rest[1] and "/".join(rest[2:]) in _PER_REGION:
        return ParsedKey(net, _PER_REGION["/".join(rest[2:])], region=rest[1])
    if len(rest) == 3 and rest[0] == "alive" and rest[1] and rest[2]:
        return ParsedKey(net, "alive", service=rest[1], instance=rest[2])
    if len(rest) == 4 and rest[0] == "control" and rest[1] in ("progress", "done") and rest[2] and rest[3]:
        return ParsedKey(net, rest[1], service=rest[2], instance=rest[3])
    raise ValueError(f"unknown bintrack key: {key!r}")
