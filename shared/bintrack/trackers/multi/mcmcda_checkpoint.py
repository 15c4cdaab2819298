"""Checkpoints of online MCMCDA taken by older versions: what they lack is rebuilt from what
they hold, so that a service restarted on a newer version resumes exactly where it stopped."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from bintrack.trackers.multi.mcmcda import OnlineMCMCDA


def upgrade_checkpoint(chain: OnlineMCMCDA) -> None:
    """Complete ``chain``, just unpickled: a checkpoint taken before the gate tables (``_gates``;
    it had ``_by_scan``) gets them from its window, as :meth:`~OnlineMCMCDA.step` made them."""
    chain.__dict__.setdefault("_rates", None)  # before online rate estimates (adapt_rates)
    chain.__dict__.setdefault("field_depth", None)  # before exits (exit_depth): its tracker sets it
    for report in chain._reports.values():  # before entries (entry_depth): the window's reports
        if not hasattr(report, "weight"):    # are past scans', never entries again
            report.weight = 1.0
    if "_gates" in chain.__dict__:
        return
    chain.__dict__.pop("_by_scan", None)
    chain._gates, now = {}, chain._scan
    for k, _, ids in chain._scans:
        chain._scan = k
        chain._add_gates(ids)
    chain._scan = now
