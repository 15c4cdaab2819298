"""What the recorder keeps of the samples it hears: every valid message of its network but the
progress reports, each once, with its event time (DESIGN §6)."""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from bintrack.keys import ParsedKey, parse_key
from bintrack.live.recording import KIND_TYPES, event_time
from bintrack.live.track_ledger import TRACK_KINDS, TrackLedger
from bintrack.message_codec import MessageError, decode_view, is_resent

# outputs a restarted service may send again, recorded once (transitions are not here: they
# carry their seq, and remembering them per sensor would cost memory that grows for long)
RESULTS = frozenset({"estimate", "fusion_reports", "tracks", "laser_objects", "motion_velocity", "region_reports",
                     "region_tracks"})
# replay says its end of stream again until every awaited service has reported done (and a
# finished service reports done again each time), and its last tick while an acknowledgement
# is overdue: each recorded once
REPEATED = frozenset({"eos", "done", "clock"})
DEDUPE_AFTER_RETURN = 1024  # result messages checked for duplicates after a service came back
RECENT_PER_KEY = 64  # payloads remembered per key of RESULTS, to record a message sent again only once
PARSED_KEYS = 65536  # distinct keys whose parse is remembered (a bound against key floods)

log = logging.getLogger("bintrack")


@dataclass
class Admitted:
    """A sample to record: its key's parse, its message (a view) and its event time (s)."""

    parsed: ParsedKey
    message: object
    t: float


class RecordFilter:
    """Decides, sample by sample, what is recorded; ``report(key, reason)`` counts a refusal."""

    def __init__(self, report: Callable[[str, str], None]):
        self.report = report
        self.parsed: dict[str, tuple] = {}  # key → (its ParsedKey, its message type)
        self.raw_last: dict[str, float] = {}  # raw key → event time of the newest sample recorded (keys of parsed)
        self.recent: dict[str, deque[bytes]] = {}
        self.resent_dropped = 0  # raw samples a restarted replay sent again that were already recorded
        self.dedupe_left = 0  # result messages still checked for duplicates after a return
        self.gone: set[tuple[str, str]] = set()  # services whose tokens went
        self.last_t = 0.0  # event time of the newest message recorded
        self.gap_from: float | None = None  # after a restart: event time up to which the file was kept
        self.tracks = TrackLedger()  # the track sets in the file: each recorded once

    def restarted(self) -> None:
        """The recorder restarted: what its predecessor recorded since its last flush is lost."""
        self.gap_from = self.last_t
        self.tracks.returned()

    def check_gap(self, kind: str, t: float, path: str) -> None:
        """At the first tick after a restart, or the end of stream if no tick follows (a kill
        after the last tick): up to there, what the lost chunk held is not coming back; say so."""
        if self.gap_from is not None and kind in ("clock", "eos"):
            log.warning("recorder: recording again from t=%g s; the raw samples, transitions and estimates "
                        "published between t=%g s and then are missing from %s (track sets fetched)",
                        t, self.gap_from, path)
            self.gap_from = None

    def on_presence(self, parsed: ParsedKey, present: bool) -> None:
        """A service's token came or went: one that comes back (a restart, a router outage) may
        send again what it sent before, which is then recorded once."""
        if parsed.kind != "alive":
            return
        entry = (parsed.service, parsed.instance)
        if present and entry in self.gone:
            self.dedupe_left = DEDUPE_AFTER_RETURN
            self.tracks.returned()
        (self.gone.discard if present else self.gone.add)(entry)

    def kept(self, key: str, payload: bytes, t: float | None = None, kind: str | None = None) -> None:
        """``payload`` on ``key`` (of key kind ``kind``, event time ``t`` s) is in the file
        (recorded, copied or fetched after a loss)."""
        if kind in TRACK_KINDS:
            self.tracks.add(key, t, payload)
        self.recent.setdefault(key, deque(maxlen=RECENT_PER_KEY)).append(payload)

    def admit(self, key: str, payload: bytes, attachment: bytes | None) -> Admitted | None:
        """The sample to record, or None: an unknown key, a progress report, a bad payload, a
        duplicate after a service came back, an end of stream or done report said again, or a
        raw sample a restarted replay sent again."""
        known = self.parsed.get(key)
        if known is None:
            try:
                parsed = parse_key(key)
                known = (parsed, KIND_TYPES[parsed.kind])
            except (ValueError, KeyError):
                self.report(key, "unknown key: not a key of a bintrack message")
                return None
            if len(self.parsed) >= PARSED_KEYS:
                self.parsed.clear()
                self.raw_last.clear()
            self.parsed[key] = known
        parsed, cls = known
        if parsed.kind in ("progress", "region_progress"):
            return None
        if parsed.kind in REPEATED and payload in self.recent.get(key, ()):
            return None
        try:
            message = decode_view(cls, payload)
        except MessageError as exc:
            self.report(key, exc.reason)
            return None
        t = event_time(message)
        t = self.last_t if t is None else t
        if parsed.kind in TRACK_KINDS and self.tracks.duplicate(key, t, payload):
            self.report(key, f"duplicate: the track set at t={t:g} s is recorded already")
            return None
        if parsed.kind in RESULTS and self.dedupe_left > 0:
            # an upstream service came back (restart, router): what it sends again is recorded
            # once. Only then: equal messages can be legitimate (a relay of equal estimates).
            self.dedupe_left -= 1
            if payload in self.recent.get(key, ()):
                self.report(key, "duplicate: the same message again, after a restart")
                return None
        if parsed.kind == "raw":
            if attachment is not None and t <= self.raw_last.get(key, -math.inf) and is_resent(attachment):
                self.resent_dropped += 1  # a restarted replay sent it again; it is here already
                return None
            self.raw_last[key] = t
        elif parsed.kind == "clock" and self.resent_dropped:
            log.info("recorder: %d raw samples a restarted replay sent again were already recorded; "
                     "recorded once", self.resent_dropped)
            self.resent_dropped = 0
        return Admitted(parsed, message, t)

    def recorded(self, admitted: Admitted, key: str, payload: bytes) -> None:
        """``admitted`` was written."""
        if admitted.parsed.kind in RESULTS or admitted.parsed.kind in REPEATED:
            self.kept(key, payload, admitted.t, admitted.parsed.kind)
        self.last_t = max(self.last_t, admitted.t)
