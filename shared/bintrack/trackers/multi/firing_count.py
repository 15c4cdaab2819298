"""How many people a scan's firing sensors speak for: a count filter over the scans (real PIR).

A room's count changes slowly (people come and go through its doors), while the number of
sensors that fire in a scan, k, grows with it about linearly. A hidden Markov model over the
count n, where someone comes or goes with probability ``switch`` per scan and

    k ~ Normal(a·n + b, b + a·n),

filtered forward, gives the count from the detections alone. b = Σ_i pfa_i, the false alarms of
an empty room, and a is what the disks say one person fires, Σ_i pd_i over the sensors covering
where they stand, averaged over where the tracker has placed people so far (until it has placed
any, over the cells inside the sensors' hull). ``benchmarks/real_pir_count.py`` shows why a
comes from the placed people and not from the floor: the count is very sensitive to it.
"""

from __future__ import annotations

import numpy as np

PRIOR_MOST = 30
"""before the first scan, every count from 0 to this is as likely (the filter holds larger ones
too, up to its ``most``)"""
PRIOR_WEIGHT = 20.0
"""the floor's average of a counts as this many placed people"""
_LEAST_VARIANCE = 0.25  # firings², so that an empty room's k = 0 is not infinitely sure


class FiringCount:
    """The count filter (module docstring): ``switch`` per scan; ``floor`` the firing sensors of
    one person averaged over the floor inside the sensors' hull, a's value until people are
    placed; ``false_alarms`` b = Σ pfa; ``most`` the largest count it holds (at least
    ``PRIOR_MOST``; the fusion gives it twice the deployment's sensors)."""

    def __init__(self, switch: float, floor: float, false_alarms: float, most: int = PRIOR_MOST):
        self.switch = switch
        self._counts = np.arange(max(most, PRIOR_MOST) + 1)
        self.b = false_alarms
        self._sum = PRIOR_WEIGHT * floor
        self._weight = PRIOR_WEIGHT
        self.belief = np.where(self._counts <= PRIOR_MOST, 1.0 / (PRIOR_MOST + 1), 0.0)
        """P(n) after the last scan"""

    def __setstate__(self, state: dict) -> None:
        """From a checkpoint; one made before the filter held more than 30 people kept its move
        as a matrix, whose entry (1, 0) is switch / 2."""
        move = state.pop("_move", None)
        if move is not None:
            state["switch"] = 2.0 * float(move[1, 0])
        self.__dict__.update(state)

    def _moved(self) -> np.ndarray:
        """The belief one scan on: someone comes or goes with probability ``switch``, half each
        way; the count 0 cannot fall nor the largest rise, so there it stays with 1 − switch/2."""
        s = self.switch
        held = self.belief / np.concatenate(([1.0 - s / 2], np.ones(len(self.belief) - 2), [1.0 - s / 2]))
        out = (1.0 - s) * held
        out[1:] += s / 2 * held[:-1]
        out[:-1] += s / 2 * held[1:]
        return out

    @property
    def a(self) -> float:
        """Firing sensors per person: the running mean of their expected firings at the placed people."""
        return self._sum / self._weight

    def update(self, fired: int) -> float:
        """One scan in which ``fired`` sensors fire; returns log p(fired | the scans before), nats."""
        belief = self._moved()
        mean = self.a * self._counts + self.b
        var = np.maximum(mean, _LEAST_VARIANCE)
        log_l = -0.5 * (fired - mean) ** 2 / var - 0.5 * np.log(2 * np.pi * var)
        top = float(log_l.max())
        belief = belief * np.exp(log_l - top)
        total = float(belief.sum())
        self.belief = belief / total
        return top + float(np.log(total))

    def beyond(self, placed: int) -> int:
        """How many people more than ``placed`` the count holds at least as likely as not: the
        largest j with P(n ≥ placed + j) ≥ ½ (0 if none)."""
        at_least = np.cumsum(self.belief[::-1])[::-1]  # at_least[m] = P(n ≥ m)
        more = 0
        while placed + more + 1 < len(at_least) and at_least[placed + more + 1] >= 0.5:
            more += 1
        return more

    def placed(self, firings: np.ndarray) -> None:
        """The people a scan placed, by the firing sensors each is expected to give where it
        stands (Σ pd of the disks covering it): they join the mean ``a``."""
        self._sum += float(np.sum(firings))
        self._weight += len(firings)
