"""Key expressions of the bus: build them for a network and parse them back, both from one table.

Every key is ``bintrack/<net>/<suffix>``; ``<net>`` is the deployment name. ``KINDS`` holds the
suffix of every kind of key, once: ``Keys`` builds each kind from it and ``parse_key`` parses it
back, so a kind cannot be built without being parsed.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

from bintrack.deployment_model import check_sensor_id

ROOT = "bintrack"


@dataclass(frozen=True)
class KeyKind:
    """One kind of key: ``suffix`` is its chunks after ``bintrack/<net>/``, a chunk in braces
    (``{sensor}``, ``{region}``, ``{service}``, ``{instance}``) being a field of ``ParsedKey``."""

    kind: str
    suffix: str
    what: str

    @property
    def chunks(self) -> tuple[str, ...]:
        return tuple(self.suffix.split("/"))

    @property
    def fields(self) -> tuple[str, ...]:
        """The fields of this kind, in key order (the builder's parameters)."""
        return tuple(c[1:-1] for c in self.chunks if _is_field(c))


def _is_field(chunk: str) -> bool:
    return chunk.startswith("{") and chunk.endswith("}")


KINDS: tuple[KeyKind, ...] = (
    KeyKind("raw", "raw/{sensor}", "a sensor's raw samples (`RawSample`), from replay"),
    KeyKind("transition", "sensor/{sensor}/transition", "a sensor's detection transitions (`Transition`)"),
    KeyKind("state", "sensor/{sensor}/state", "queryable: a sensor's state and its recent transitions (`SensorState`)"),
    KeyKind("estimate", "peer/{sensor}/estimate", "a peer agent's local estimate (`LocalEstimate`)"),
    KeyKind("fusion_reports", "fusion/reports", "the base station's position reports of a scan (`PositionReports`)"),
    KeyKind("tracks", "tracks", "the track set (`TrackSet`); also a queryable (`?after=T`)"),
    KeyKind("region_reports", "region/{region}/fusion/reports", "a region's base station: its `PositionReports`"),
    KeyKind("region_tracks", "region/{region}/tracks",
            "a region's base station: its `TrackSet` (local ids); the merge makes `tracks` of them"),
    KeyKind("region_progress", "region/{region}/progress",
            "a region's base station: a `Clock` after each tick, the event time up to which its tracks are final"),
    KeyKind("region_alive", "region/{region}/alive", "liveliness token of a region's base station (one per region)"),
    KeyKind("laser_objects", "laser/objects", "the laser tracker's objects (`LineObjectEstimate`)"),
    KeyKind("motion_velocity", "motion/velocity", "the motion trackers' velocity estimates (`VelocityEstimate`)"),
    KeyKind("truth", "truth", "replay of a dataset with truth.csv: where the targets really are (`TruthSample`)"),
    KeyKind("deployment", "deployment", "queryable: the deployment (`Deployment`), served by replay"),
    KeyKind("clock", "clock", "event time (`Clock`), from replay"),
    KeyKind("eos", "control/eos", "end of stream (`EndOfStream`), from replay"),
    KeyKind("recent", "control/recent",
            "queryable: replay's raw samples since a clock tick (`?after=T`), for a restarted sensor agent"),
    KeyKind("alive", "alive/{service}/{instance}", "liveliness token of a service instance"),
    KeyKind("progress", "control/progress/{service}/{instance}",
            "flow control: the event time (`Clock`) a service instance has processed"),
    KeyKind("done", "control/done/{service}/{instance}",
            "flow control: a service instance has processed the end of stream (`EndOfStream`)"),
)
KIND = {k.kind: k for k in KINDS}


def _chunk(value: str, what: str) -> str:
    if not value or any(c in value for c in "/*$?#") or value.strip() != value:
        raise ValueError(f"{what} {value!r} cannot be a key-expression chunk")
    return value


def _any_or(check):
    return lambda value: value if value == "*" else check(value)


# field -> its check when building a key (``*`` is a wildcard for subscriptions)
_FIELD_CHECKS = {
    "sensor": _any_or(check_sensor_id),
    "region": _any_or(lambda v: _chunk(v, "region name")),
    "service": _any_or(lambda v: _chunk(v, "service name")),
    "instance": _any_or(lambda v: _chunk(v, "instance id")),
}


@dataclass(frozen=True)
class Keys:
    """The key expressions of one network (``net``); one method per kind of ``KINDS``, named as
    the kind, its parameters the kind's fields (``*``, the default, for any)."""

    net: str = "default"

    def __post_init__(self):
        _chunk(self.net, "network name")

    @property
    def prefix(self) -> str:
        return f"{ROOT}/{self.net}"

    def all(self) -> str:
        """Everything of this network: what the recorder subscribes to."""
        return f"{self.prefix}/**"

    def build(self, kind: str, **fields: str) -> str:
        """The key of ``kind`` (a ``KINDS`` entry) with these fields (each ``*`` when omitted)."""
        spec = KIND[kind]
        unknown = set(fields) - set(spec.fields)
        if unknown:
            raise TypeError(f"key kind {kind!r} has no field {sorted(unknown)}")
        chunks = [_FIELD_CHECKS[c[1:-1]](fields.get(c[1:-1], "*")) if _is_field(c) else c for c in spec.chunks]
        return "/".join((self.prefix, *chunks))

    def raw(self, sensor: str = "*") -> str:
        return self.build("raw", sensor=sensor)

    def transition(self, sensor: str = "*") -> str:
        return self.build("transition", sensor=sensor)

    def state(self, sensor: str = "*") -> str:
        return self.build("state", sensor=sensor)

    def estimate(self, sensor: str = "*") -> str:
        return self.build("estimate", sensor=sensor)

    def fusion_reports(self) -> str:
        return self.build("fusion_reports")

    def tracks(self) -> str:
        return self.build("tracks")

    def region_reports(self, region: str = "*") -> str:
        """A region's base station: its ``PositionReports`` (DESIGN §9)."""
        return self.build("region_reports", region=region)

    def region_tracks(self, region: str = "*") -> str:
        """A region's base station: its ``TrackSet`` (local ids); the merge makes ``tracks`` of them."""
        return self.build("region_tracks", region=region)

    def region_progress(self, region: str = "*") -> str:
        """A region's base station: a ``Clock`` after each tick, the event time up to which its
        tracks are final (every scan at or before it was published), and in ``sent`` how many
        scans it has published (the merge counts them, DESIGN §11)."""
        return self.build("region_progress", region=region)

    def region_alive(self, region: str = "*") -> str:
        """Liveliness token of a region's base station (one per region)."""
        return self.build("region_alive", region=region)

    def laser_objects(self) -> str:
        return self.build("laser_objects")

    def motion_velocity(self) -> str:
        return self.build("motion_velocity")

    def truth(self) -> str:
        """Replay of a dataset with truth.csv: where the targets really are (``TruthSample``)."""
        return self.build("truth")

    def deployment(self) -> str:
        return self.build("deployment")

    def clock(self) -> str:
        return self.build("clock")

    def eos(self) -> str:
        return self.build("eos")

    def recent(self) -> str:
        """Replay's queryable of the raw samples it published since a clock tick (``?after=T``),
        for a sensor agent that restarts from its checkpoint."""
        return self.build("recent")

    def alive(self, service: str = "*", instance: str = "*") -> str:
        """Liveliness token key of a service instance (``*`` for any)."""
        return self.build("alive", service=service, instance=instance)

    def progress(self, service: str = "*", instance: str = "*") -> str:
        """Flow control: the event time (``Clock``) a service instance has processed."""
        return self.build("progress", service=service, instance=instance)

    def done(self, service: str = "*", instance: str = "*") -> str:
        """Flow control: a service instance has processed the end of stream (``EndOfStream``)."""
        return self.build("done", service=service, instance=instance)


@dataclass(frozen=True)
class ParsedKey:
    """What a concrete key names: ``kind`` is the ``kind`` of one of ``KINDS`` (raw, transition,
    state, estimate, fusion_reports, tracks, region_reports, region_tracks, region_progress,
    region_alive, laser_objects, motion_velocity, truth, deployment, clock, eos, recent, alive,
    progress, done), and the fields its suffix has."""

    net: str
    kind: str
    sensor: str | None = None
    service: str | None = None
    instance: str | None = None
    region: str | None = None


def parse_key(key: str) -> ParsedKey:
    """Parse a concrete bintrack key; raises ValueError for anything else."""
    return _parse_key(str(key))


# (number of chunks, literal chunks by position, field names by position, kind) of each kind
_PATTERNS = [(len(k.chunks), {i: c for i, c in enumerate(k.chunks) if not _is_field(c)},
              {i: c[1:-1] for i, c in enumerate(k.chunks) if _is_field(c)}, k.kind) for k in KINDS]


@lru_cache(maxsize=65536)  # a network has few keys; parsed once each (a bound against key floods)
def _parse_key(key: str) -> ParsedKey:
    parts = key.split("/")
    if len(parts) < 3 or parts[0] != ROOT or not parts[1]:
        raise ValueError(f"not a bintrack key: {key!r}")
    net, rest = parts[1], parts[2:]
    for size, literals, fields, kind in _PATTERNS:
        if (len(rest) == size and all(rest[i] == c for i, c in literals.items())
                and all(rest[i] for i in fields)):
            return ParsedKey(net, kind, **{name: rest[i] for i, name in fields.items()})
    raise ValueError(f"unknown bintrack key: {key!r}")
