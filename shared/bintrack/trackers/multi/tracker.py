"""The base station's multi-target tracker (paper 004): grid fusion of each scan's detections
into position reports, then online MCMCDA over a sliding window of scans. The fusion of a scan
is told where the tracks of the previous scans expect their targets (``FusionConfig.track_aided``).

Peer agents' ``LocalEstimate``s (arc, sector or a baseline) can join the fused reports, so that
single-target estimates feed multi-target tracking: each becomes a report in the first scan at
or after its time, with an isotropic variance from its arc (the position is uniform along an
arc of length R·arc) or, without an arc, R²/4.
"""

from __future__ import annotations

import math
from dataclasses import replace

from bintrack.trackers.multi.fusion import Scan, ScanFusion
from bintrack.trackers.multi.fusion_config import FusionConfig
from bintrack.trackers.multi.mcmcda import OnlineMCMCDA
from bintrack.trackers.multi.mcmcda_config import MCMCDAConfig
from bintrack.bus_payloads import LocalEstimate, PositionReport, PositionReports, TrackSet, Transition
from bintrack.deployment_model import Deployment
from bintrack.trackers.base import Tracker, TrackerOutput

_MIN_ESTIMATE_VARIANCE = 1.0  # m²: an arc of length 0 still has the sensing model's error


class MCMCDATracker:
    """Transitions of disk sensors in event-time order → per scan, the ``PositionReports`` of
    the fusion (§III, plus any peer estimates) and the ``TrackSet`` of online MCMCDA (§IV) at
    the scan's time.

    ``config`` is in metres and seconds, like :class:`MCMCDAConfig`'s defaults; the tracker
    converts it to the deployment's units (``Deployment.metres_per_unit``), so that a field
    described in feet is tracked as the same field in metres.

    ``peer``: a peer tracker run on the same transitions whose estimates join the reports
    (offline); live, the base station hands the peers' estimates to :meth:`update`. An estimate
    whose scan was already tracked, or of a node that is not a range sensor, is not taken and
    counted in ``late_estimates``.
    """

    name = "mcmcda"
    revisions: list | None = None
    """kept (:meth:`keep_revisions`): after each scan, :meth:`OnlineMCMCDA.associations` of the
    window; the fixed-lag smoother takes them, one per ``TrackSet``"""

    def __init__(self, deployment: Deployment, fusion: FusionConfig = FusionConfig(),
                 config: MCMCDAConfig = MCMCDAConfig(), peer: Tracker | None = None):
        self.fusion = ScanFusion(deployment, fusion)
        region = deployment.region
        self.mcmcda = OnlineMCMCDA(config.in_units(deployment.metres_per_unit), self.name,
                                   area=(region.xmax - region.xmin) * (region.ymax - region.ymin),
                                   field_depth=self.fusion.grid.depth)
        self._track_aided = fusion.clustering == "fit" and fusion.track_aided
        self.peer = peer
        self._ranges = {s.id: s.range for s in deployment.sensors if hasattr(s, "range")}
        self._min_estimate_variance = _MIN_ESTIMATE_VARIANCE / deployment.metres_per_unit ** 2
        self._pending: dict[int, list[tuple[float, str, PositionReport]]] = {}
        self.late_estimates = 0

    def __setstate__(self, state: dict) -> None:
        """From a checkpoint. One taken before exits (``MCMCDAConfig.exit_depth``) goes on as a
        tracker made now would: the sensor field's edge from its fusion, and the default exit
        depth (none for real PIR, :mod:`.pir_settings`) in its units. One taken before
        ``FusionConfig.multiplicity`` or ``shared_support`` goes on with the fit its window was fused
        with: targets over the union of the disks, the bars it stored, copies without an evidence bar."""
        self.__dict__.update(state)
        chain = self.mcmcda
        if chain.field_depth is None:
            chain.field_depth = self.fusion.grid.depth
        if "exit_depth" not in vars(chain.config):
            metres_per_unit = math.sqrt(_MIN_ESTIMATE_VARIANCE / self._min_estimate_variance)
            real_pir = any(getattr(s, "hold", None) is not None for s in self.fusion.sensors.values())
            exit_depth = None if real_pir else MCMCDAConfig().in_units(metres_per_unit).exit_depth
            chain.config = replace(chain.config, exit_depth=exit_depth)
        grid = self.fusion.grid
        before = {"multiplicity": False, "shared_support": None}  # what a fit without the field did
        missing = {k: v for k, v in before.items() if k not in vars(grid.config)}
        if missing:
            grid.config = grid._fit.config = replace(grid.config, **missing)

    @property
    def motion(self) -> tuple[float, float, float]:
        """The fixed-lag smoother's constant-velocity model, in the deployment's units: (q,
        units²/s³: ``smooth_noise``, else ``process_noise``; the variance of a new track's speed,
        units²/s²; the least variance of a report, units², ``extra_variance``)."""
        c = self.mcmcda.config
        q = c.process_noise if c.smooth_noise is None else c.smooth_noise
        return q, c.initial_speed ** 2, c.extra_variance

    def keep_revisions(self) -> None:
        """From now on, after each scan append the MAP's association of the window's reports to
        ``revisions`` (:mod:`bintrack.trackers.multi.fixed_lag` reads and empties it)."""
        self.revisions = []

    def update(self, message: Transition | LocalEstimate) -> list[PositionReports | TrackSet]:
        """A transition: the scans it completes, fused and tracked. A peer's estimate: a report
        of its scan, when that scan is tracked (no output now)."""
        if isinstance(message, LocalEstimate):
            self._add_estimate(message)
            return []
        if self.peer is not None:
            self._take(self.peer.update(message))
        return self._track(self.fusion.update(message))

    def flush(self, t: float) -> list[PositionReports | TrackSet]:
        if self.peer is not None:
            self._take(self.peer.flush(t))
        return self._track(self.fusion.flush(t))

    def _add_estimate(self, estimate: LocalEstimate) -> None:
        """Make ``estimate`` a report of the first scan at or after its time; counted in
        ``late_estimates`` (and not taken) when that scan was already processed or the node is
        not a range sensor."""
        sensing_range = self._ranges.get(estimate.node)
        scan = self.fusion.scan_of(estimate.t)
        if sensing_range is None or scan < self.fusion.next_scan():
            self.late_estimates += 1
            return
        if estimate.arc is not None:
            variance = max((sensing_range * estimate.arc) ** 2 / 12.0, self._min_estimate_variance)
        else:
            variance = sensing_range ** 2 / 4.0
        report = PositionReport(x=estimate.x, y=estimate.y, cov=((variance, 0.0), (0.0, variance)))
        self._pending.setdefault(scan, []).append((estimate.t, estimate.node, report))

    def _take(self, outputs: list[TrackerOutput]) -> None:
        for out in outputs:
            if isinstance(out, LocalEstimate):
                self._add_estimate(out)

    def _track(self, scans: list[Scan]) -> list[PositionReports | TrackSet]:
        out: list[PositionReports | TrackSet] = []
        for snapshot in scans:
            self.mcmcda.skip(snapshot.skipped)
            expected = self.mcmcda.expected(snapshot.t) if self._track_aided else ()
            scan = self.fusion.fuse(snapshot, expected)
            extra = sorted(self._pending.pop(self.fusion.scan_of(scan.t), []), key=lambda e: (e[0], e[1]))
            if extra:
                scan = PositionReports(t=scan.t, reports=[*scan.reports, *(r for _, _, r in extra)])
            out.append(scan)
            out.append(self.mcmcda.step(scan))
            if self.revisions is not None:
                self.revisions.append(self.mcmcda.associations())
        return out
