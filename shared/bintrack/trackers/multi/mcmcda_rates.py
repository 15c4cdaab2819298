"""Online estimates of MCMCDA's detection probability p_d and false-report density λ_f (eq. 3)
from the scans its window has fixed (``MCMCDAConfig.adapt_rates``; issue 42).

When a scan leaves the window its reports are settled: a report in a track is a detection, the
others are false reports; a track begun before that scan (it has an anchor) and with a report
there or after it was present, and a hit if its report is there (a track's first report is a
detection by construction and is not counted). Over the last ``scans`` fixed scans,

    p̂_d = (hits + m p_d⁰) / (present + m),   λ̂_f = (false + s A λ_f⁰) / ((n + s) A),

with the configured p_d⁰, λ_f⁰ as a prior worth m = ``PRIOR_TRACK_SCANS`` track-scans and
s = ``PRIOR_SCANS`` scans, n the scans counted and A the field's area (units²). p̂_d stays within
``PD_RANGE``. It leans high where tracks break often: the scans after a track's last report
are not counted (it may have ended there).
"""

from __future__ import annotations

from collections import deque

PRIOR_TRACK_SCANS = 20.0
PRIOR_SCANS = 20.0
PD_RANGE = (0.3, 0.98)


class RateEstimate:
    """The running counts behind p̂_d and λ̂_f (see the module text)."""

    def __init__(self, pd: float, false_alarm_rate: float, area: float, scans: int):
        self.prior_pd, self.prior_rate, self.area = pd, false_alarm_rate, area
        self.counts: deque[tuple[int, int, int]] = deque(maxlen=scans)

    def observe(self, hits: int, present: int, false: int) -> None:
        """One fixed scan: tracks with a report there, tracks present, reports in no track."""
        self.counts.append((hits, present, false))

    @property
    def pd(self) -> float:
        """p̂_d: probability that a present target yields a report in a scan."""
        hits = sum(c[0] for c in self.counts)
        present = sum(c[1] for c in self.counts)
        value = (hits + PRIOR_TRACK_SCANS * self.prior_pd) / (present + PRIOR_TRACK_SCANS)
        return min(max(value, PD_RANGE[0]), PD_RANGE[1])

    @property
    def false_alarm_rate(self) -> float:
        """λ̂_f: false reports per unit area (units²) per scan."""
        false = sum(c[2] for c in self.counts)
        n = len(self.counts)
        return (false + PRIOR_SCANS * self.area * self.prior_rate) / ((n + PRIOR_SCANS) * self.area)
