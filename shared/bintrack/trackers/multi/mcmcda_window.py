"""The sliding window of online MCMCDA (paper 004 §IV; Oh et al. §IV-C): its reports, the tracks
of the chain's state, the anchors that fix a track's reports once they leave the window, and the
gates that say which reports may follow which in a track.

Each scan the window slides; reports that leave it are fixed with their track: the track's
filtered state becomes its *anchor*, from which the track continues inside the window, and whose
identity it keeps. An anchor is dropped d̄ + 1 scans after its report, or with ``still_misses``
(a target that stood still) that many scans after it where it lies inside the sensor field.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from bintrack.trackers.multi.kalman_model import kf_predict, kf_update


@dataclass
class Anchor:
    """The fixed part of a track: its identity and per-axis filtered state at its last fixed report."""

    identity: int
    scan: int
    t: float
    x: tuple[float, float, float, float, float]  # p, v, P_pp, P_pv, P_vv of axis x
    y: tuple[float, float, float, float, float]
    reports: int


@dataclass(slots=True)
class WindowReport:
    """A report of the window: its scan, time (s), position and per-axis variance (the report's
    covariance diagonal plus ``extra_variance``, units²), whether it is a shared copy, and its
    evidence (nats, :attr:`~bintrack.bus_payloads.PositionReport.weight`)."""

    scan: int
    t: float
    x: float
    y: float
    rx: float
    ry: float
    shared: bool = False
    weight: float = 1.0


class Gate:
    """The window's reports that may follow one report or anchor in a track (``_follows``):
    ``at[k]`` those of scan k in report order, ``all`` all of them. Which reports may follow
    which depends only on the two and the configuration, so the chain looks it up here."""

    __slots__ = ("scan", "at", "all")

    def __init__(self, scan: int):
        self.scan = scan
        self.at: dict[int, list[int]] = {}
        self.all: set[int] = set()

    def add(self, scan: int, rids: list[int]) -> None:
        if rids:
            self.at[scan] = rids
            self.all.update(rids)


@dataclass(slots=True)
class ChainTrack:
    """A track of the chain's state: its window reports (ids, in scan order), its anchor if it
    has fixed reports, and its identity once it has one."""

    reports: tuple[int, ...]
    anchor: Anchor | None = None
    label: int | None = None


class ScanWindow:
    """The window's part of :class:`~bintrack.trackers.multi.mcmcda.OnlineMCMCDA`: fixing the
    reports that leave it, dropping the tracks that end, a track's filter, and the gates.

    It works on the sampler's state: ``config``, ``_scan`` (the current scan), ``_scans``
    (scan, t, report ids) of the window, ``_reports``, ``_gates``, ``_tracks`` and, while a
    chain runs, ``_anchor_gates``."""

    def _fix_oldest(self) -> None:
        k, t, ids = self._scans.popleft()
        gone = set(ids)
        if self._rates is not None:  # before fixing: which tracks have a report at scan k
            used = sum(1 for track in self._tracks if gone.intersection(track.reports))
            # a track's first report is a detection by construction: only tracks begun before k
            # (with an anchor) and going on after it count as present there
            hits = sum(1 for track in self._tracks if track.anchor is not None and gone.intersection(track.reports))
            missed = sum(1 for track in self._tracks if track.anchor is not None and track.reports
                         and not gone.intersection(track.reports))
            self._rates.observe(hits, hits + missed, len(ids) - used)
        for track in self._tracks:
            fixed = [r for r in track.reports if r in gone]
            if not fixed:
                continue
            rid = fixed[0]
            rep = self._reports[rid]
            if track.label is None:
                track.label = self._new_identity()
            if track.anchor is None:
                ax, ay = self._initial(rep)
                track.anchor = Anchor(track.label, k, t, ax, ay, 1)
            else:
                a = track.anchor
                sx, sy, _ = self._advance(a.x, a.y, a.t, rep, a.scan)
                track.anchor = Anchor(a.identity, k, t, sx, sy, a.reports + 1)
            track.reports = tuple(r for r in track.reports if r != rid)
        for rid in ids:
            del self._reports[rid]
            del self._gates[rid]
            self._owner.pop(rid, None)

    def associations(self) -> list[tuple[float, dict[int, tuple[float, float, float, float]]]]:
        """The MAP's association of the window's reports, oldest scan first: per scan, its time
        (s) and identity → (x, y, x variance, y variance) (units, units²; the variances as the
        chain scores the report) of the report each labelled track holds there (a track without
        an identity yet is left out)."""
        held = {k: (t, {}) for k, t, _ in self._scans}
        for track in self._tracks:
            if track.label is None:
                continue
            for rid in track.reports:
                report = self._reports[rid]
                held[report.scan][1][track.label] = (report.x, report.y, report.rx, report.ry)
        return list(held.values())

    def _expire_anchors(self) -> None:
        keep = []
        for track in self._tracks:
            a = track.anchor
            if not track.reports and (a is None or not self._may_follow(a.scan, a.x[0], a.y[0])):
                continue
            if track.anchor is None and len(track.reports) < 2:
                continue
            keep.append(track)
        self._tracks = keep

    def _initial(self, rep: WindowReport):
        v0 = self.config.initial_speed ** 2
        return (rep.x, 0.0, rep.rx, 0.0, v0), (rep.y, 0.0, rep.ry, 0.0, v0)

    # ------------------------------------------------------------------ scoring

    def _advance(self, sx, sy, t: float, rep: WindowReport, scan: int):
        """Predict the per-axis states from time ``t`` (s, scan ``scan``) to ``rep``'s and
        update them with it: (state x, state y, log-likelihood of the innovations). After a gap
        of over d̄ + 1 scans (``still_misses``) the target stood still: it is where it was, spread
        by half ``still_reach``, and walks on at a velocity drawn afresh."""
        c = self.config
        if rep.scan - scan > c.max_misses + 1:
            spread, v0 = (c.still_reach / 2) ** 2, c.initial_speed ** 2
            sx, sy = (sx[0], 0.0, sx[2] + spread, 0.0, v0), (sy[0], 0.0, sy[2] + spread, 0.0, v0)
        else:
            sx, sy = kf_predict(sx, rep.t - t, c.process_noise), kf_predict(sy, rep.t - t, c.process_noise)
        sx, lx = kf_update(sx, rep.x, rep.rx)
        sy, ly = kf_update(sy, rep.y, rep.ry)
        return sx, sy, lx + ly

    def _start(self, track: ChainTrack):
        """The track's filter before its remaining window reports: (state x, state y, scan and
        time of the last report taken, reports taken, reports still to take)."""
        reps = [self._reports[r] for r in track.reports]
        if track.anchor is not None:
            a = track.anchor
            return a.x, a.y, a.scan, a.t, a.reports, reps
        sx, sy = self._initial(reps[0])
        return sx, sy, reps[0].scan, reps[0].t, 1, reps[1:]

    # ------------------------------------------------------------------ gate

    def _follows(self, a_scan: int, a_t: float, ax: float, ay: float, a_var: float, rid: int) -> bool:
        """Whether report ``rid`` may follow, in a track, a report or anchor of scan ``a_scan``
        at time ``a_t`` (s) and (``ax``, ``ay``) with position variance ``a_var``: at most
        d̄ + 1 scans later and within v̄·Δt plus ``gate_sigmas`` σ of it; or, for a target that
        stood still (``still_misses``), later and within ``still_reach`` plus those σ."""
        c = self.config
        rep = self._reports[rid]
        gap = rep.scan - a_scan
        if gap < 1:
            return False
        if gap <= c.max_misses + 1:
            reach = c.max_speed * (rep.t - a_t) + c.gate_sigmas * math.sqrt(a_var + max(rep.rx, rep.ry))
        elif self._may_follow(a_scan, ax, ay, rep.scan):
            reach = c.still_reach + c.gate_sigmas * math.sqrt(a_var + max(rep.rx, rep.ry))
        else:
            return False
        return (rep.x - ax) ** 2 + (rep.y - ay) ** 2 <= reach * reach

    def _may_follow(self, a_scan: int, ax: float, ay: float, scan: int | None = None) -> bool:
        """Whether a report of ``scan`` (default: the current one) may still follow a track that
        ended at scan ``a_scan`` at (``ax``, ``ay``): within d̄ + 1 scans, or within
        ``still_misses`` + 1 where it ended ``still_depth`` or more inside the sensor field."""
        c = self.config
        gap = (self._scan if scan is None else scan) - a_scan
        if gap <= c.max_misses + 1:
            return True
        depth = self.field_depth
        return gap <= c.still_misses + 1 and depth is not None and depth(ax, ay) >= c.still_depth

    def _add_gates(self, ids: list[int]) -> None:
        """Gates for the new scan's reports ``ids``, which join the gates of the reports they may follow."""
        for rid, gate in self._gates.items():
            rep = self._reports[rid]
            gate.add(self._scan, [r for r in ids if self._follows(rep.scan, rep.t, rep.x, rep.y, max(rep.rx, rep.ry), r)])
        for rid in ids:
            self._gates[rid] = Gate(self._scan)

    def _anchor_gate(self, a: Anchor) -> Gate:
        gate = Gate(a.scan)
        end = (a.scan, a.t, a.x[0], a.y[0], max(a.x[2], a.y[2]))
        for k, _, ids in self._scans:
            gate.add(k, [r for r in ids if self._follows(*end, r)])
        return gate

    def _gate(self, track: ChainTrack) -> Gate:
        """The gate of the track's last report, or of its anchor if it has none."""
        if track.reports:
            return self._gates[track.reports[-1]]
        return self._anchor_gates[id(track.anchor)]

    def _end_of(self, track: ChainTrack) -> tuple[int, float, float, float, float] | None:
        """(scan, t, x, y, position variance) of the track's last report or anchor."""
        if track.reports:
            rep = self._reports[track.reports[-1]]
            return rep.scan, rep.t, rep.x, rep.y, max(rep.rx, rep.ry)
        if track.anchor is not None:
            a = track.anchor
            return a.scan, a.t, a.x[0], a.y[0], max(a.x[2], a.y[2])
        return None

    def _valid(self, track: ChainTrack) -> bool:
        if track.anchor is None:
            if len(track.reports) < 2:
                return False
            gate, rest = self._gates[track.reports[0]], track.reports[1:]
        else:
            gate, rest = self._anchor_gates[id(track.anchor)], track.reports
        for rid in rest:
            if rid not in gate.all:
                return False
            gate = self._gates[rid]
        return True
