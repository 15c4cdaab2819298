"""Whether a peer's ``LocalEstimate`` may be taken by a base station."""

from __future__ import annotations

from collections.abc import Container

from bintrack.keys import Keys
from bintrack.bus_payloads import LocalEstimate


def estimate_problem(estimate: LocalEstimate, key: str, keys: Keys, nodes: Container[str], tracker: str) -> str | None:
    """Why ``estimate``, which came on ``key``, is refused (one line), or None: it must be of a
    known node, on that node's own key, and by ``tracker``."""
    if estimate.node not in nodes or key != keys.estimate(estimate.node):
        return f"estimate of unknown or mismatched node {estimate.node!r}"
    if estimate.tracker != tracker:
        return f"estimate of tracker {estimate.tracker!r}, this base station runs {tracker!r}"
    return None
