"""The base station's adaptive basis tracker for line (laser) sensors (paper 003), push-style.

Transitions of line sensors (value 1 at each beam crossing, in event-time order) are grouped
into *passes* — one object in the region at a time (paper 003 §2) — and each pass becomes an
object of :class:`~bintrack.trackers.laser.adaptive_basis.AdaptiveBasis`. A pass is complete when

1. every line sensor has detected it (a straight pass meets a beam at most once), or
2. a sensor that already detected it fires again (that detection starts the next pass), or
3. ``gap`` seconds of event time pass without a detection.

Sensors that miss a pass (woke too late, beam outside the track) simply have no time for it
(paper 003 Fig. 3); rules 2–3 close such passes. The default ``gap`` is half the shortest
calibration pass's crossing time (t_exit − t_entry of the deployment's ``calibration`` passes,
DESIGN §6): detections of one pass lie within its crossing time, and on the testbed the longest
silence inside a pass is about a quarter of it. Without calibration passes it is learnt as half
the longest detection span of the passes every sensor detected (until the first such pass, only
rules 1–2 and the end of the stream close passes).

Phase 1 runs on the first four passes that allow it (six sensors detected the first three, five
of them the fourth, all four within 12 consecutive passes, and the input is not degenerate). From then on every completed pass is
estimated and every parameter refined (phase 2: ``phase2="lsq"``, the default, solves eq. 5 over
all passes so far to its least-squares optimum; ``"paper"`` makes ``iterations`` Newton
iterations per pass, §7.2), and phase 3 maps the result to real-world coordinates: from the
sensors' known positions (``x``, ``y``; at least six, not on one line) and/or known beams
(``a``, ``b``), else from the ``calibration`` passes. :attr:`AdaptiveBasisTracker.frame_source`
says which was used, :attr:`~AdaptiveBasisTracker.frame_reason` why, and
:attr:`~AdaptiveBasisTracker.frame_residual` how well it fits (RMS, units: the distance of each
known point from where the frame puts it — calibration entry/exit points, or known sensor
positions from their estimated beams, or each known beam's ends in the region from the
estimated beam). A residual above :data:`FRAME_RESIDUAL_WARNING` adds one warning to
:attr:`~AdaptiveBasisTracker.warnings` (naming the calibration passes); :meth:`info` gathers
all this.

Output: one :class:`LineObjectEstimate` per pass, in pass order, each exactly once — the passes
before phase 1 all at once when phase 1 succeeds, later ones when they complete — and then, with
``revise`` (default), revised estimates of passes already given (``revision`` 1, 2, …;
:mod:`.revisions`), after each pass and at the end of the stream (``flush(inf)``). With ``revise``
a pass's first estimate is the best known when it closes: the re-solve over the passes so far,
this one included (phases 1–3's estimate where the re-solve fails or has none of it). ``t_first`` and
``t_last`` are the pass's first and last detection times (s); entry and exit are where the
estimated straight path crosses the region's border (units; the positions at the first and last
detection if the path misses the region); ``vx``, ``vy`` its real-world velocity (units/s, equal
to (exit − entry) / (exit time − entry time)); ``entry_sd``, ``exit_sd`` the standard deviations
(units, √ of the 2 × 2 covariance's trace) of the path's position at the entry and exit times,
from eq. 5's least-squares covariance (the real-world frame counted as exact), or from the
re-solve's covariance when it gave the estimate. A pass with fewer
than four detections by estimated beams cannot be estimated and is skipped (listed in
:attr:`skipped`).
"""

from __future__ import annotations

import math

import numpy as np

from bintrack.trackers.laser.adaptive_basis import PHASE2_METHODS, AdaptiveBasis
from bintrack.trackers.laser.line_model import DegenerateError, border_times
from bintrack.trackers.laser.phase1_closed_form import PHASE1_SENSORS
from bintrack.trackers.laser.phase3_frame import (
    Frame,
    calibration_conditioning,
    collinear,
    frame_from_points,
    frame_from_sensors,
)
from bintrack.trackers.laser.revisions import Revisions
from bintrack.errors import TrackerConfigError
from bintrack.bus_payloads import LineObjectEstimate, Transition
from bintrack.deployment_model import Deployment, LineSensor

NAME = "adaptive-basis"
FRAME_RESIDUAL_WARNING = 0.25  # units (ft on the testbed): a frame misfit above this is warned about
# a misfit is warned about from this pass on: with ±0.02 s timing noise the frame fitted after
# pass 4 misfits correct calibration passes by up to 0.31 ft, from pass 8 on by at most 0.24 ft
# (simulated testbeds, seeds 21–40)
FRAME_WARNING_PASSES = 8


class AdaptiveBasisTracker:
    """Paper 003 at the base station: ``update(transition)`` / ``flush(t)`` → ``LineObjectEstimate``s.

    ``phase2``: "lsq" (least-squares optimum of eq. 5 after every pass, default) or "paper"
    (``iterations`` Newton iterations per pass, paper: 5). ``gap`` (s): silence that ends a pass
    (default: see the module docstring). Raises :class:`TrackerConfigError` if the deployment has fewer
    than six line sensors or nothing can fix real-world coordinates.
    """

    name = NAME

    def __init__(self, deployment: Deployment, *, iterations: int = 5, gap: float | None = None,
                 phase2: str = "lsq", revise: bool = True):
        sensors = [s for s in deployment.sensors if isinstance(s, LineSensor)]
        if not sensors:
            raise TrackerConfigError(f"tracker {NAME} needs line sensors; this deployment has none")
        if len(sensors) < PHASE1_SENSORS:
            raise TrackerConfigError(f"tracker {NAME} needs at least {PHASE1_SENSORS} line sensors (paper 003 §4); "
                               f"this deployment has {len(sensors)}")
        if iterations < 0:
            raise TrackerConfigError(f"tracker {NAME}: iterations must be ≥ 0, got {iterations}")
        if phase2 not in PHASE2_METHODS:
            raise TrackerConfigError(f"tracker {NAME}: phase 2 must be one of {', '.join(PHASE2_METHODS)}, got {phase2!r}")
        if gap is not None and not (math.isfinite(gap) and gap > 0):
            raise TrackerConfigError(f"tracker {NAME}: gap must be a positive number of seconds, got {gap}")
        self.deployment = deployment
        self.ids = [s.id for s in sensors]
        self._index = {sid: k for k, sid in enumerate(self.ids)}
        self.positions = {k: (s.x, s.y) for k, s in enumerate(sensors) if s.x is not None}
        self.known_beams = {k: (s.a, s.b) for k, s in enumerate(sensors) if s.a is not None}
        region = deployment.region
        self._box = (region.xmin, region.ymin, region.xmax, region.ymax)
        self.calibration = list(deployment.calibration.passes) if deployment.calibration else []
        self.frame_plan, self.frame_reason = self._plan_frame()
        if not self.frame_plan:
            raise TrackerConfigError(f"tracker {NAME} cannot place its estimates in real-world coordinates: "
                               f"{self.frame_reason}")
        self.basis = AdaptiveBasis(len(sensors), iterations=iterations, phase2=phase2)
        self.gap_source = "option" if gap is not None else ("calibration" if self.calibration else "learnt")
        if gap is None and self.calibration:
            gap = 0.5 * min(p.t_exit - p.t_entry for p in self.calibration)
        self.gap = gap
        self.frame: Frame | None = None
        self.frame_source: str | None = None
        self.frame_errors: dict[str, str] = {}  # the last reason each source failed, if it did
        self.frame_residual: float | None = None  # RMS misfit of the frame's known points, units
        self.frame_points: str = ""  # what the residual was measured on
        self.warnings: list[str] = [f"{NAME}: {reason}" for reason in
                                    (calibration_conditioning(self.calibration) if "calibration" in self.frame_plan
                                     else [])]
        self._residual_warned = False
        self._frame_inputs: tuple = ("", [], None)  # what fixed the frame: for the uncertainty
        self._warn_after = FRAME_WARNING_PASSES
        self.skipped: list[int] = []
        self.passes: list[tuple[float, float]] = []  # (t_first, t_last) per completed pass
        self._current: dict[int, float] = {}
        self._last = -math.inf
        self._emitted = 0
        self.revisions = Revisions(self.positions, self.known_beams, self._box) if revise else None
        self._finished = False

    def __setstate__(self, state: dict) -> None:
        """A checkpoint pickled before the revisions existed resumes as that version ran: without them."""
        state.setdefault("revisions", None)
        state.setdefault("_finished", False)
        state.setdefault("_residual_warned", bool(state.get("warnings")))
        self.__dict__.update(state)

    # ---------------------------------------------------------------- phase 3 plan

    def _plan_frame(self) -> tuple[tuple[str, ...], str]:
        """Which sources can fix real-world coordinates, in the order they are tried, and why."""
        plan = []
        equations = len(self.positions) + 2 * len(self.known_beams)
        reasons = []
        if equations >= 6 and (len(self.known_beams) >= 3 or not collinear(list(self.positions.values()))):
            plan.append("sensors")
            reasons.append(f"{len(self.positions)} known sensor positions and {len(self.known_beams)} known beams")
        elif self.positions and collinear(list(self.positions.values())):
            reasons.append(f"the {len(self.positions)} known sensor positions lie on one line, so they cannot fix "
                           "the frame (paper 003 eq. 29 is singular)")
        else:
            reasons.append(f"{len(self.positions)} known sensor positions and {len(self.known_beams)} known beams "
                           "are too few (six positions, or three beams, are needed)")
        if len(self.calibration) >= 2:
            plan.append("calibration")
            reasons.append(f"{len(self.calibration)} calibration passes" + (" (fallback)" if plan[0] == "sensors" else ""))
        else:
            reasons.append(f"{len(self.calibration)} calibration passes (two are needed)")
        return tuple(plan), "; ".join(reasons)

    def _calibration_object(self, t_entry: float, t_exit: float) -> int | None:
        """The pass with the most detections within [t_entry, t_exit] (s), or None."""
        best, count = None, 0
        times = self.basis.times
        for obj in range(self.basis.objects):
            col = times[:, obj]
            inside = int(np.sum((col >= t_entry) & (col <= t_exit)))
            if inside > count:
                best, count = obj, inside
        return best

    def _compute_frame(self) -> Frame | None:
        basis = self.basis
        for source in self.frame_plan:
            try:
                if source == "sensors":
                    known = basis.line_known()
                    positions = {k: p for k, p in self.positions.items() if known[k]}
                    beams = {k: ab for k, ab in self.known_beams.items() if known[k]}
                    frame = frame_from_sensors(basis.lines, positions, beams)
                    self._sensor_residual(frame, positions, beams)
                    self._frame_inputs = ("sensors", positions, beams)
                    return frame
                pairs, used, matched = [], [], []
                for cal in self.calibration:
                    obj = self._calibration_object(cal.t_entry, cal.t_exit)
                    if obj is None or not basis.object_known()[obj]:
                        continue
                    pairs.append((basis.position(obj, cal.t_entry), cal.entry))
                    pairs.append((basis.position(obj, cal.t_exit), cal.exit))
                    used.append(cal.pass_)
                    matched.append((obj, cal))
                frame = frame_from_points(pairs)
                self._frame_inputs = ("calibration", matched, None)
                misfit = [np.hypot(*(frame.points(q) - np.asarray(p))) for q, p in pairs]
                self._residual(frame, misfit, "the entry and exit points of calibration passes "
                               + ", ".join(map(str, used)), "check those passes' entry/exit points and times")
                return frame
            except DegenerateError as exc:
                self.frame_errors[source] = str(exc)
                continue
        return None

    def _sensor_residual(self, frame: Frame, positions: dict, beams: dict) -> None:
        """Residual of a frame from sensors: each known position's distance from its estimated
        beam, each known beam's two ends in the region from the estimated beam (units)."""
        real = frame.lines(self.basis.lines)
        misfit = []
        for k, p in positions.items():
            misfit.append(abs(real[k] @ np.asarray(p, dtype=float) - 1.0) / np.hypot(*real[k]))
        for k, (a, b) in beams.items():
            foot = np.array([a, b]) / (a * a + b * b)
            span = border_times(foot, np.array([-b, a]), 0.0, self._box)
            for s in span or ():
                point = foot + np.array([-b, a]) * (s - 0.0)
                misfit.append(abs(real[k] @ point - 1.0) / np.hypot(*real[k]))
        names = [self.ids[k] for k in positions] + [self.ids[k] for k in beams]
        self._residual(frame, misfit, f"the known positions/beams of sensors {', '.join(dict.fromkeys(names))}",
                       "check those sensors' x, y, a, b")

    def _residual(self, frame: Frame, misfit: list[float], what: str, advice: str) -> None:
        self.frame_residual = float(np.sqrt(np.mean(np.square(misfit)))) if misfit else None
        self.frame_points = what
        if (self.frame_residual is not None and self.frame_residual > FRAME_RESIDUAL_WARNING
                and len(self.passes) >= self._warn_after and not self._residual_warned):
            self._residual_warned = True
            units = self.deployment.units
            self.warnings.append(
                f"{NAME}: the real-world frame misfits {what} by {self.frame_residual:.3g} {units} RMS "
                f"(above {FRAME_RESIDUAL_WARNING:g} {units}) after pass {len(self.passes)}: {advice}")

    def info(self) -> dict:
        """What the tracker knows about its own state: phase 2 method, frame source, reason,
        residual (units) and what it was measured on, gap (s), passes, skipped passes, warnings."""
        solve = self.basis.last_solve
        return {"phase2": self.basis.phase2, "frame_source": self.frame_source, "frame_reason": self.frame_reason,
                "frame_residual": self.frame_residual, "frame_points": self.frame_points,
                "units": self.deployment.units, "gap": self.gap, "gap_source": self.gap_source,
                "passes": len(self.passes), "estimated": self._emitted - len(self.skipped),
                "skipped": list(self.skipped), "cost": None if solve is None else solve.cost,
                "gradient": None if solve is None else solve.gradient, "warnings": list(self.warnings)}

    # ---------------------------------------------------------------- push interface

    def update(self, transition: Transition) -> list[LineObjectEstimate]:
        """Take one line-sensor transition (value 1 = beam crossed at ``t``; others are ignored)."""
        k = self._index.get(transition.sensor)
        if k is None or transition.value != 1:
            return []
        out: list[LineObjectEstimate] = []
        if self._current:
            if self.gap is not None and transition.t > self._last + self.gap:
                out += self._close()
            elif k in self._current:
                if self._current[k] == transition.t:
                    return out  # the same crossing twice
                out += self._close()
        self._current[k] = transition.t
        self._last = transition.t
        if len(self._current) == len(self.ids):
            out += self._close()
        return out

    def flush(self, t: float) -> list[LineObjectEstimate]:
        """No transition at or before ``t`` (s) will come: close the open pass if its gap has
        elapsed (``t = inf``: close it anyway) and return what can be estimated."""
        out = []
        if self._current and (t == math.inf or (self.gap is not None and t >= self._last + self.gap)):
            out = self._close()
        if t == math.inf and self.revisions is not None and not self._finished:
            self._finished = True
            out += self.revisions.final(self.basis.t_refs)
        return out

    # ---------------------------------------------------------------- passes

    def _close(self) -> list[LineObjectEstimate]:
        col = np.full(len(self.ids), np.nan)
        for k, t in self._current.items():
            col[k] = t
        self._current = {}
        self.passes.append((float(np.nanmin(col)), float(np.nanmax(col))))
        if self.gap_source == "learnt" and np.all(np.isfinite(col)):
            self.gap = max(self.gap or 0.0, 0.5 * float(np.ptp(col)))
        self.basis.add_object(col)
        if not self.basis.try_initialise():
            return []
        frame = self._compute_frame()
        if frame is None:
            return []
        self.frame, self.frame_source = frame, frame.source
        resolved = self.revisions is not None and self._resolve()
        out = []
        known = self.basis.object_known()
        for obj in range(self._emitted, self.basis.objects):
            estimate = None
            if known[obj]:
                estimate = (resolved and self._estimate_at_close(obj)) or self._estimate(obj)
            if estimate is None:
                self.skipped.append(obj + 1)
            else:
                out.append(estimate)
                if self.revisions is not None:
                    self.revisions.publish(obj, estimate)
        self._emitted = self.basis.objects
        if resolved:
            out += self.revisions.check(self.basis.t_refs)
        return out

    def _estimate_at_close(self, obj: int) -> LineObjectEstimate | None:
        """Pass ``obj``'s first estimate from the re-solve over the passes so far (this one
        included), or None where the re-solve has none."""
        t_first, t_last = self.passes[obj]
        template = LineObjectEstimate(object=obj + 1, t_first=t_first, t_last=t_last, entry_x=0.0, entry_y=0.0,
                                      exit_x=0.0, exit_y=0.0, vx=0.0, vy=0.0)
        got = self.revisions.estimate(obj, float(self.basis.t_refs[obj]), template)
        return None if got is None else got[0]

    def _resolve(self) -> bool:
        """Re-solve every pass in real-world coordinates (:mod:`.revisions`); False if it failed."""
        basis, frame = self.basis, self.frame
        lines = np.where(basis.line_known()[:, None], frame.lines(np.nan_to_num(basis.lines)), np.nan)
        centres, velocities = frame.points(basis.centres), frame.vectors(basis.velocities)
        passes = np.column_stack([velocities[:, 0], centres[:, 0], velocities[:, 1], centres[:, 1]])
        passes[~basis.object_known()] = np.nan
        fixed = {}
        for cal in self.calibration:
            obj = self._calibration_object(cal.t_entry, cal.t_exit)
            if obj is not None and basis.object_known()[obj]:
                v = (np.asarray(cal.exit, dtype=float) - cal.entry) / (cal.t_exit - cal.t_entry)
                c = np.asarray(cal.entry, dtype=float) + v * (basis.t_refs[obj] - cal.t_entry)
                fixed[obj] = np.array([v[0], c[0], v[1], c[1]])
        return self.revisions.resolve(basis.times, basis.t_refs, lines, passes, fixed) is not None

    def _point_sds(self, obj: int, times: tuple[float, float]) -> list[float | None]:
        """Standard deviations (units, √ trace) of pass ``obj``'s real-world positions at
        ``times`` (s): eq. 5's joint covariance of the beams, this pass and the calibration
        passes, propagated through phase 3 (the frame is refitted from the perturbed estimates)
        by central differences."""
        basis = self.basis
        source, inputs, beams_known = self._frame_inputs
        others = [o for o, _ in inputs] if source == "calibration" else []
        objs = [obj] + [o for o in dict.fromkeys(others) if o != obj]
        cov = basis.covariance(objs)
        if cov is None or not np.all(np.isfinite(cov)):
            return [None, None]
        m = basis.sensors
        w = np.column_stack([basis.velocities[:, 0], basis.centres[:, 0], basis.velocities[:, 1], basis.centres[:, 1]])
        x0 = np.concatenate([basis.lines.ravel(), w[objs].ravel()])
        t_refs = basis.t_refs

        def points(x: np.ndarray) -> np.ndarray:
            ws = {o: x[2 * m + 4 * i:2 * m + 4 * i + 4] for i, o in enumerate(objs)}

            def at(o, t):
                return ws[o][[1, 3]] + ws[o][[0, 2]] * (t - t_refs[o])

            if source == "sensors":
                frame = frame_from_sensors(x[:2 * m].reshape(m, 2), inputs, beams_known)
            else:
                frame = frame_from_points([(at(o, c.t_entry), c.entry) for o, c in inputs]
                                          + [(at(o, c.t_exit), c.exit) for o, c in inputs])
            return np.concatenate([frame.points(at(obj, t)) for t in times])

        sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        active = np.flatnonzero(sd > 0)
        jac = np.zeros((4, len(x0)))
        try:
            for i in active:
                step = np.zeros_like(x0)
                step[i] = 1e-3 * sd[i]
                jac[:, i] = (points(x0 + step) - points(x0 - step)) / (2 * step[i])
        except DegenerateError:
            return [None, None]
        var = jac @ cov @ jac.T
        out = []
        for i in (0, 2):
            value = math.sqrt(max(float(var[i, i] + var[i + 1, i + 1]), 0.0))
            out.append(value if math.isfinite(value) else None)
        return out

    def _estimate(self, obj: int) -> LineObjectEstimate | None:
        basis, frame = self.basis, self.frame
        t_ref = float(basis.t_refs[obj])
        centre = frame.points(basis.centres[obj])
        velocity = frame.vectors(basis.velocities[obj])
        t_first, t_last = self.passes[obj]
        times = border_times(centre, velocity, t_ref, self._box) or (t_first, t_last)
        entry, exit_ = (centre + velocity * (t - t_ref) for t in times)
        values = [*entry, *exit_, *velocity]
        if not all(math.isfinite(v) for v in values):
            return None
        sds = self._point_sds(obj, times)
        return LineObjectEstimate(object=obj + 1, t_first=t_first, t_last=t_last,
                                  entry_x=float(entry[0]), entry_y=float(entry[1]),
                                  exit_x=float(exit_[0]), exit_y=float(exit_[1]),
                                  vx=float(velocity[0]), vy=float(velocity[1]),
                                  entry_sd=sds[0], exit_sd=sds[1])

    # ---------------------------------------------------------------- views

    def beams(self) -> dict[str, tuple[float, float]]:
        """The estimated beams (a, b) in real-world units⁻¹ by sensor id (phase 3 applied); empty
        before the first frame."""
        if self.frame is None:
            return {}
        known = self.basis.line_known()
        real = self.frame.lines(self.basis.lines)
        return {sid: (float(real[k, 0]), float(real[k, 1])) for k, sid in enumerate(self.ids) if known[k]}
