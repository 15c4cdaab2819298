"""The base station's multi-target tracker (paper 004): grid fusion of each scan's detections
into position reports, then online MCMCDA over a sliding window of scans."""

from __future__ import annotations

from ..fusion import FusionConfig, ScanFusion
from ..mcmcda import MCMCDAConfig, OnlineMCMCDA
from ..messages import Deployment, PositionReports, Transition, TrackSet


class MCMCDATracker:
    """Transitions of disk sensors in event-time order → per scan, the ``PositionReports`` of
    the fusion (§III) and the ``TrackSet`` of online MCMCDA (§IV) at the scan's time."""

    name = "mcmcda"

    def __init__(self, deployment: Deployment, fusion: FusionConfig = FusionConfig(),
                 config: MCMCDAConfig = MCMCDAConfig()):
        self.fusion = ScanFusion(deployment, fusion)
        self.mcmcda = OnlineMCMCDA(config, self.name)

    def update(self, transition: Transition) -> list[PositionReports | TrackSet]:
        return self._track(self.fusion.update(transition))

    def flush(self, t: float) -> list[PositionReports | TrackSet]:
        return self._track(self.fusion.flush(t))

    def _track(self, scans: list[PositionReports]) -> list[PositionReports | TrackSet]:
        out: list[PositionReports | TrackSet] = []
        for scan in scans:
            out.append(scan)
            out.append(self.mcmcda.step(scan))
        return out
