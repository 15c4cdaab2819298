"""Revised estimates of past passes: every pass re-solved once later passes sharpen the beams.

After every pass the tracker's state (phases 1–3) is re-solved in real-world coordinates
(:mod:`.realworld_solve`: time residuals, calibration passes and known positions held exact),
from the previous re-solve's beams and from the beams through the calibration passes' crossing
points; the solution of smaller residual variance is kept. The tracker publishes a pass's first
estimate from the re-solve at its close (:meth:`Revisions.estimate`). A pass already published
gets a revised ``LineObjectEstimate`` (``revision`` 1, 2, …) when its entry or exit point has
moved by more than the standard deviation it was last published with. A pass is *settled* — never checked again —
once the beams' share of its entry and exit covariance allows no move above
:data:`SETTLE_UNITS` (3 standard deviations): better beams cannot change it by more. At the end of
the stream (:meth:`Revisions.final`) every pass whose last published point differs from the final
re-solve by more than :data:`SETTLE_UNITS` gets a last revision, so the latest revision of every
pass is its final estimate (to within that). Work per pass: one re-solve and one check per
unsettled pass, both linear in the passes.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence

import numpy as np

from bintrack.trackers.laser.line_model import border_times
from bintrack.trackers.laser.pass_bound import beam_directions, crossing_jacobian
from bintrack.trackers.laser.realworld_solve import RealWorldSolution, solve_real_world
from bintrack.bus_payloads import LineObjectEstimate

SETTLE_UNITS = 0.01  # units (ft on the testbed): a pass that cannot move more is not checked again
SETTLE_SDS = 3.0


class Revisions:
    """The re-solve and the revision bookkeeping of one tracker. ``positions``/``beams``: known
    sensor positions (index → (x, y)) and beams (index → (a, b)), units; ``box`` the region."""

    def __init__(self, positions: Mapping[int, Sequence[float]], beams: Mapping[int, Sequence[float]],
                 box: tuple[float, float, float, float]):
        self.positions, self.known_beams, self.box = dict(positions), dict(beams), box
        self.published: dict[int, LineObjectEstimate] = {}  # object index → its latest message
        self.settled: set[int] = set()
        self.solution: RealWorldSolution | None = None

    def _constrain(self, lines: np.ndarray) -> np.ndarray:
        """Each beam moved onto its known position's constraint n·q = 1; known beams as given."""
        lines = lines.copy()
        for k, q in self.positions.items():
            q = np.asarray(q, dtype=float)
            lines[k] = lines[k] + (1.0 - lines[k] @ q) * q / (q @ q)
        for k, ab in self.known_beams.items():
            lines[k] = ab
        return lines

    def _starts(self, times: np.ndarray, t_refs: np.ndarray, lines: np.ndarray,
                fixed: Mapping[int, np.ndarray]) -> list[np.ndarray]:
        """Beams to start from: the last re-solve's (phases 1–3's where it had none), and the
        beams through the points where the calibration passes crossed them (and their known
        positions) — a start that does not depend on phase 1."""
        warm = lines.copy()
        if self.solution is not None:
            had = np.all(np.isfinite(self.solution.lines), axis=1)
            warm[had] = self.solution.lines[had]
        starts = [self._constrain(warm)]
        through = warm.copy()
        for k in range(len(lines)):
            points = [w[[1, 3]] + w[[0, 2]] * (times[k, o] - t_refs[o]) for o, w in fixed.items()
                      if np.isfinite(times[k, o])]
            if k in self.positions:
                points.append(np.asarray(self.positions[k], dtype=float))
            if len(points) >= 2:
                through[k] = np.linalg.lstsq(np.array(points), np.ones(len(points)), rcond=None)[0]
        if fixed:
            starts.append(self._constrain(through))
        return starts

    def resolve(self, times: np.ndarray, t_refs: np.ndarray, lines: np.ndarray, passes: np.ndarray,
                fixed: Mapping[int, np.ndarray]) -> RealWorldSolution | None:
        """Re-solve from phases 1–3's real-world ``lines`` (m × 2) and ``passes`` (n × 4 at
        ``t_refs``; NaN rows not estimated); ``fixed`` maps a calibration pass to its exact w.
        Of the starts (:meth:`_starts`), the solution with the smallest residual variance is kept."""
        known = np.all(np.isfinite(lines), axis=1)
        if not known.all():
            return None  # a beam not estimated yet: nothing to revise with
        passes = passes.copy()
        for obj, w in fixed.items():
            passes[obj] = w
        best = None
        for start in self._starts(times, t_refs, lines, fixed):
            dirs = beam_directions(start, self.positions, tuple(self.known_beams))
            solution = solve_real_world(times, t_refs, start, passes, tuple(fixed), dirs)
            if solution is not None and (best is None or solution.variance < best.variance):
                best = solution
        if best is not None:
            self.solution = best
        return best

    def estimate(self, obj: int, t_ref: float, first: LineObjectEstimate) -> tuple[LineObjectEstimate, float] | None:
        """Pass ``obj``'s estimate from the last re-solve (the fields of ``first`` it does not
        change kept) and the largest move better beams could still make (units, 3 sd); None if
        the re-solve has no estimate of it."""
        sol = self.solution
        if sol is None or obj not in sol.covariance:
            return None
        w = sol.passes[obj]
        span = border_times(w[[1, 3]], w[[0, 2]], t_ref, self.box)
        exact = not np.any(sol.covariance[obj])  # a calibration pass: no uncertainty, no derivative needed
        jac = (np.zeros((2, 4)), np.zeros((2, 4))) if exact else crossing_jacobian(w, t_ref, self.box)
        if span is None or jac is None:
            return None
        entry, exit_ = (w[[1, 3]] + w[[0, 2]] * (t - t_ref) for t in span)
        sds = [math.sqrt(max(float(np.trace(g @ sol.covariance[obj] @ g.T)), 0.0)) for g in jac]
        room = max(SETTLE_SDS * math.sqrt(max(float(np.trace(g @ sol.beam_share[obj] @ g.T)), 0.0)) for g in jac)
        values = [*entry, *exit_, w[0], w[2], *sds]
        if not all(math.isfinite(v) for v in values):
            return None
        return first.model_copy(update={"entry_x": float(entry[0]), "entry_y": float(entry[1]),
                                        "exit_x": float(exit_[0]), "exit_y": float(exit_[1]),
                                        "vx": float(w[0]), "vy": float(w[2]),
                                        "entry_sd": sds[0], "exit_sd": sds[1]}), room

    def publish(self, obj: int, message: LineObjectEstimate) -> None:
        """Remember what was published for pass ``obj`` (its first estimate or a revision)."""
        self.published[obj] = message

    def _revise(self, obj: int, candidate: LineObjectEstimate, limit: Callable[[LineObjectEstimate], tuple]):
        last = self.published[obj]
        moved_entry = math.hypot(candidate.entry_x - last.entry_x, candidate.entry_y - last.entry_y)
        moved_exit = math.hypot(candidate.exit_x - last.exit_x, candidate.exit_y - last.exit_y)
        entry_limit, exit_limit = limit(last)
        if moved_entry <= entry_limit and moved_exit <= exit_limit:
            return None
        revised = candidate.model_copy(update={"revision": (last.revision or 0) + 1})
        self.published[obj] = revised
        return revised

    def check(self, t_refs: np.ndarray) -> list[LineObjectEstimate]:
        """After a re-solve: revisions of the published, unsettled passes that moved by more than
        their last published standard deviation (in pass order); passes that can no longer move
        by more than :data:`SETTLE_UNITS` are settled."""
        out = []
        sd = lambda m: (m.entry_sd if m.entry_sd is not None else 0.0,  # noqa: E731
                        m.exit_sd if m.exit_sd is not None else 0.0)
        for obj in sorted(self.published):
            if obj in self.settled:
                continue
            got = self.estimate(obj, float(t_refs[obj]), self.published[obj])
            if got is None:
                continue
            candidate, room = got
            revised = self._revise(obj, candidate, sd)
            if revised is not None:
                out.append(revised)
            if room <= SETTLE_UNITS:
                self.settled.add(obj)
        return out

    def final(self, t_refs: np.ndarray) -> list[LineObjectEstimate]:
        """At the end of the stream: a last revision for every published pass whose latest
        message is more than :data:`SETTLE_UNITS` from the final re-solve."""
        out = []
        for obj in sorted(self.published):
            got = self.estimate(obj, float(t_refs[obj]), self.published[obj])
            if got is not None:
                revised = self._revise(obj, got[0], lambda m: (SETTLE_UNITS, SETTLE_UNITS))
                if revised is not None:
                    out.append(revised)
        return out
