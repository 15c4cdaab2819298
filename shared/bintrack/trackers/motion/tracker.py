"""Trackers for closer/farther (motion) sensors, paper 002: four push-style base-station objects.

* :class:`VelocityPlaneTracker` (``velocity-plane``), :class:`SvmTracker` (``svm``) and
  :class:`PprTracker` (``ppr``): the velocity estimators of paper 002 §III over the periods so
  far (or the last ``window``), one :class:`~bintrack.bus_payloads.VelocityEstimate` per period
  with x, y = None (they give no position);
* :class:`MotionRandomWalkTracker` (``motion-rw``): the random-walk tracker of paper 002 §IV,
  position and velocity each period.

**Periods.** A motion sensor reports ±1 once per ``period`` P (s); its agent publishes a
transition only when the value changes (the idle value is −1, so a sensor whose first report
is −1 is silent too), and the tracker knows each sensor's status in a period from its last
transition. Period k is the event-time window [t₀ + (k − ½)P, t₀ + (k + ½)P) around its
nominal sample time t₀ + kP (``epoch`` t₀, default 0 s; P the deployment's smallest motion
period unless given). Every sensor samples once in each window as long as its sampling instant
is within ±P/2 of the nominal one — the simulator samples all sensors at exactly kP; sampling
phases or clock offsets up to ±P/2 are tolerated, beyond that a sample is filed in the
neighbouring period. A sensor with a longer period keeps its last status in between.

**Silences.** Periods more than ``MAX_SILENCE`` s after the last transition are empty time: when
a transition ends such a gap, they are passed over without an estimate.

**When an estimate is emitted.** Period k is complete when ``flush(t)`` has t at or after the
window's end (no transition of it can come any more) and some transition of period k or later
has been seen: a later transition proves that the target was still reported; after the last
transition of the stream nothing tells whether the target is still there, so those trailing
periods are not emitted (offline and live alike, whatever clock watermarks the live service
sees). Estimates are stamped t = t₀ + kP. Each tracker emits at most one estimate per period,
from the first period where its estimator is defined (e.g. the velocity plane needs a sensor
that changed sign).

Deterministic (the random-walk tracker's uniform initialisation draws from
``numpy.random.default_rng(seed)``); no I/O.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from bintrack.trackers.motion.closer_farther import VelocityFit, unit_vector
from bintrack.trackers.motion.ppr_estimator import ppr_fit
from bintrack.trackers.motion.svm_estimator import svm_fit, svm_velocity
from bintrack.trackers.motion.velocity_plane import velocity_plane
from bintrack.errors import TrackerConfigError
from bintrack.time_span import MAX_SILENCE
from bintrack.bus_payloads import Transition, VelocityEstimate
from bintrack.deployment_model import Deployment, MotionSensor


class _PeriodTracker:
    """Period bookkeeping shared by the motion trackers: statuses per period, completion,
    a window of the last periods' statuses (rows, oldest first) for the estimator."""

    name = "motion"

    def __init__(self, deployment: Deployment, *, period: float | None = None, epoch: float = 0.0,
                 window: int | None = None):
        sensors = [s for s in deployment.sensors if isinstance(s, MotionSensor)]
        if not sensors:
            raise TrackerConfigError(f"tracker {self.name} needs motion (closer/farther) sensors; this deployment has none")
        if period is not None and not (math.isfinite(period) and period > 0):
            raise TrackerConfigError(f"tracker {self.name}: period must be a positive number of seconds, got {period}")
        if window is not None and window < 1:
            raise TrackerConfigError(f"tracker {self.name}: window must be at least 1 period, got {window}")
        self.ids = [s.id for s in sensors]
        self.index = {sid: i for i, sid in enumerate(self.ids)}
        self.positions = np.array([(s.x, s.y) for s in sensors], dtype=float)
        self.period = float(period) if period is not None else float(min(s.period for s in sensors))
        self.epoch = float(epoch)
        self.window = window
        self._status = np.full(len(sensors), -1, dtype=np.int8)  # idle value of a motion sensor
        self._pending: dict[int, list[tuple[int, int]]] = {}
        self._next: int | None = None  # next period to complete
        self._last_seen: int | None = None  # period of the latest transition
        self._rows: deque[np.ndarray] = deque(maxlen=window)
        self._times: deque[float] = deque(maxlen=window)

    # ------------------------------------------------------------------ periods

    def period_of(self, t: float) -> int:
        """Index k of the period whose window [t₀ + (k − ½)P, t₀ + (k + ½)P) holds event time t (s)."""
        return math.floor((t - self.epoch) / self.period + 0.5)

    def period_time(self, k: int) -> float:
        """Nominal sample time t₀ + kP (s) of period k."""
        return self.epoch + k * self.period

    def _end(self, k: int) -> float:
        return self.epoch + (k + 0.5) * self.period

    def update(self, transition: Transition) -> list[VelocityEstimate]:
        i = self.index.get(transition.sensor)
        if i is None:  # not a motion sensor of this deployment
            return []
        k = self.period_of(transition.t)
        out: list[VelocityEstimate] = []
        if self._next is None:
            self._next = k
        # transitions come in event-time order: every period before k is over and, with this
        # transition, known to have been reported; but after MAX_SILENCE s without a transition
        # the rest of the gap is empty time, passed over
        quiet_until = k if self._last_seen is None else self._last_seen + math.ceil(MAX_SILENCE / self.period)
        while self._next < min(k, quiet_until + 1):
            out.extend(self._complete(self._next))
        self._next = max(self._next, k)
        self._pending.setdefault(max(k, self._next), []).append((i, int(transition.value)))
        self._last_seen = k if self._last_seen is None else max(self._last_seen, k)
        return out

    def flush(self, t: float) -> list[VelocityEstimate]:
        out: list[VelocityEstimate] = []
        while (self._next is not None and self._last_seen is not None and self._next <= self._last_seen
               and t >= math.nextafter(self._end(self._next), -math.inf)):
            out.extend(self._complete(self._next))
        return out

    def _complete(self, k: int) -> list[VelocityEstimate]:
        for i, value in self._pending.pop(k, []):
            self._status[i] = value
        self._rows.append(self._status.copy())
        self._times.append(self.period_time(k))
        self._next = k + 1
        estimate = self._estimate(k, np.array(self._rows), np.array(self._times))
        return [] if estimate is None else [estimate]

    def _estimate(self, k: int, rows: np.ndarray, times: np.ndarray) -> VelocityEstimate | None:
        raise NotImplementedError

    def _velocity(self, k: int, fit: VelocityFit | None) -> VelocityEstimate | None:
        if fit is None:
            return None
        return VelocityEstimate(t=self.period_time(k), method=self.name, vx=fit.vx, vy=fit.vy)


class VelocityPlaneTracker(_PeriodTracker):
    """``velocity-plane`` (paper 002 §III.A): the counters' staircase and its tangent plane.

    Options: ``window`` — periods used (default None: every period so far, the paper's batch
    counters; give e.g. 10–20 for a manoeuvring target); ``period`` (s, default the deployment's
    smallest motion period), ``epoch`` (s, default 0): see the module docstring; ``loss``,
    ``f_scale`` (counts) — the robust loss of ``scipy.optimize.least_squares`` (default
    soft_l1, 1 count)."""

    name = "velocity-plane"

    def __init__(self, deployment: Deployment, *, window: int | None = None, period: float | None = None,
                 epoch: float = 0.0, loss: str = "soft_l1", f_scale: float = 1.0):
        super().__init__(deployment, period=period, epoch=epoch, window=window)
        self.loss = loss
        self.f_scale = f_scale

    def _estimate(self, k, rows, times):
        return self._velocity(k, velocity_plane(self.positions, rows, self.period, self.loss, self.f_scale))


class SvmTracker(_PeriodTracker):
    """``svm`` (paper 002 §III.B): maximum-margin lines with a shared normal over the periods.

    Options: ``window`` (default None: every period so far), ``c`` — soft-margin slack weight
    in normalised coordinates (default 1000, used only when the periods are not separable),
    ``period``, ``epoch`` as for :class:`VelocityPlaneTracker`."""

    name = "svm"

    def __init__(self, deployment: Deployment, *, window: int | None = None, c: float = 1000.0,
                 period: float | None = None, epoch: float = 0.0):
        super().__init__(deployment, period=period, epoch=epoch, window=window)
        self.c = c

    def _estimate(self, k, rows, times):
        return self._velocity(k, svm_velocity(self.positions, rows, times, self.c))


class PprTracker(_PeriodTracker):
    """``ppr`` (paper 002 §III.C): projection pursuit regression of the counters.

    Options: ``window`` (default None: every period so far), ``grid`` — angles scanned before
    the exact refinement (default 720, 0.5°), ``period``, ``epoch`` as above."""

    name = "ppr"

    def __init__(self, deployment: Deployment, *, window: int | None = None, grid: int = 720,
                 period: float | None = None, epoch: float = 0.0):
        super().__init__(deployment, period=period, epoch=epoch, window=window)
        self.grid = grid

    def _estimate(self, k, rows, times):
        return self._velocity(k, ppr_fit(self.positions, rows, self.period, self.grid))


VELOCITY_MODELS = ("heading", "mean", "step")


def _perp(u: np.ndarray) -> np.ndarray:
    return np.array([-u[1], u[0]])


class MotionRandomWalkTracker(_PeriodTracker):
    """``motion-rw``: the random-walk tracker of paper 002 §IV (position and velocity).

    Each complete period k, with Δt the time since the previous estimate:

    1. direction u_k: the SVM normal of the last ``window`` periods (default 1: the paper's
       per-period SVM, step 2); the target's projection on u_k lies in the band between
       a_k = max s·u_k over the −1 sensors and b_k = min s·u_k over the +1 sensors (§IV.C);
    2. prediction x̃ = x̂_{k−1} + v̂·Δt; correction α along u_k to the middle of the band,
       α = (a_k + b_k)/2 − x̃·u_k (eqs. correct1–correct2), x̂_k = x̃ + α·u_k; the step velocity
       w_k = (x̂_k − x̂_{k−1})/Δt is the prediction's velocity with the α correction added;
    3. if w_k leaves mean ± σ (per component) of the last ``n`` step velocities (the paper's
       velocity model), the correction β across u (§IV.D): x̂_k += β·u_k^⊥ and
       x̂_{k−1} += β·u_{k−1}^⊥ (both stay in their bands), β the least-squares value that brings
       (x̂_k − x̂_{k−1})/Δt nearest the mean: β = −(w_k − m)·d/|d|², d = (u_k^⊥ − u_{k−1}^⊥)/Δt;
       none when d = 0 (rectilinear uniform motion: "no correction factor can be calculated");
       |β| ≤ ``beta_max`` (units) — a safeguard of ours: with per-period SVM directions d is
       mostly noise and an unbounded β diverges;
    4. feedback (§IV.E): the corrected x̂_{k−1} gives the recorded step velocity (rows already
       emitted are not revised); x̂_k is kept within the deployment's region (ours).

    The velocity v̂ used to predict and emitted (``velocity``): ``"heading"`` (default) the SVM
    direction u_k times the mean speed along it of the last ``n`` steps — the paper takes the
    direction from the SVM and the speed from the corrections; ``"mean"`` the mean of the last
    ``n`` step velocities (the paper's velocity model v̄); ``"step"`` the last step velocity.

    Initialisation (§IV.F): the first period's position is drawn uniformly in its band within
    the deployment's region (``seed``), the velocity is ``speed``·u (``speed`` units/s, default
    None = 0: unknown). Emits x̂_k and v̂ (units/s) at t₀ + kP.

    Options: ``window`` (periods of the direction SVM, default 1), ``n`` (velocity history,
    default 10), ``beta_max`` (units, default 10; both tuned on 40 random-walk runs, see
    docs/paper002.md), ``velocity`` (default "heading"), ``speed``, ``seed`` (default 0), ``c``
    (soft-margin weight, default 1000), ``period``, ``epoch`` (see the module docstring)."""

    name = "motion-rw"

    def __init__(self, deployment: Deployment, *, window: int = 1, n: int = 10, beta_max: float = 10.0,
                 velocity: str = "heading", speed: float | None = None, seed: int = 0, c: float = 1000.0,
                 period: float | None = None, epoch: float = 0.0):
        super().__init__(deployment, period=period, epoch=epoch, window=window)
        if velocity not in VELOCITY_MODELS:
            raise TrackerConfigError(f"tracker {self.name}: velocity must be one of {', '.join(VELOCITY_MODELS)}, got {velocity!r}")
        self.velocity = velocity
        if n < 2:
            raise TrackerConfigError(f"tracker {self.name}: n must be at least 2 velocity estimates, got {n}")
        self.region = deployment.region
        self.n = n
        self.beta_max = float(beta_max)
        self.initial_speed = 0.0 if speed is None else float(speed)
        self.c = c
        self._rng = np.random.default_rng(seed)
        self._x: np.ndarray | None = None  # x̂ of the last estimated period
        self._v: np.ndarray | None = None  # latest velocity estimate
        self._u: np.ndarray | None = None  # direction of the last estimated period
        self._t: float | None = None
        self._history: deque[np.ndarray] = deque(maxlen=n)

    # ------------------------------------------------------------------ geometry of a period

    def _direction(self, rows: np.ndarray) -> np.ndarray | None:
        result = svm_fit(self.positions, rows, self.c)
        if result is None:
            return None
        return unit_vector(result.heading)

    def _band(self, status: np.ndarray, u: np.ndarray) -> tuple[float, float]:
        """(a, b): the target's projection on u lies in [a, b] (−inf/inf when a class is empty)."""
        proj = self.positions @ u
        behind, ahead = proj[status == -1], proj[status == 1]
        return (float(behind.max()) if len(behind) else -math.inf, float(ahead.min()) if len(ahead) else math.inf)

    def _initial_position(self, u: np.ndarray, a: float, b: float) -> np.ndarray:
        """Uniform draw in {x in the region : a ≤ x·u ≤ b} (paper 002 §IV.F)."""
        r = self.region
        corners = np.array([(r.xmin, r.ymin), (r.xmax, r.ymin), (r.xmin, r.ymax), (r.xmax, r.ymax)])
        along, across = corners @ u, corners @ _perp(u)
        lo, hi = max(a, along.min()), min(b, along.max())
        if not lo <= hi:  # the band misses the region: its nearest edge
            lo = hi = float(np.clip((a if math.isfinite(a) else b), along.min(), along.max()))
        for _ in range(1000):
            p = self._rng.uniform(lo, hi, 64)
            q = self._rng.uniform(across.min(), across.max(), 64)
            x = p[:, None] * u + q[:, None] * _perp(u)
            ok = (x[:, 0] >= r.xmin) & (x[:, 0] <= r.xmax) & (x[:, 1] >= r.ymin) & (x[:, 1] <= r.ymax)
            if ok.any():
                return x[np.argmax(ok)]
        return np.array([(r.xmin + r.xmax) / 2, (r.ymin + r.ymax) / 2])

    # ------------------------------------------------------------------ one period

    def _estimate(self, k, rows, times):
        status = rows[-1]
        t = float(times[-1])
        u = self._direction(rows)
        if u is None:
            if self._u is None:
                return None  # nothing separates yet: no direction to start from
            u = self._u
        a, b = self._band(status, u)
        if self._x is None:
            self._x = self._initial_position(u, a, b)
            self._v = self.initial_speed * u
            self._u, self._t = u, t
            return self._emit(t)
        dt = t - self._t
        predicted = self._x + self._v * dt
        p = float(predicted @ u)
        if math.isfinite(a) and math.isfinite(b):
            alpha = (a + b) / 2 - p
        else:  # one class only: move just into the half-plane
            alpha = max(a - p, 0.0) if math.isfinite(a) else min(b - p, 0.0)
        x_new = predicted + alpha * u
        x_old = self._x
        step = (x_new - x_old) / dt
        if self.beta_max > 0 and len(self._history) >= 2:
            hist = np.array(self._history)
            mean, sigma = hist.mean(axis=0), hist.std(axis=0)
            if np.any(np.abs(step - mean) > sigma):
                d = (_perp(u) - _perp(self._u)) / dt
                dd = float(d @ d)
                if dd > 1e-18:
                    beta = float(np.clip(-((step - mean) @ d) / dd, -self.beta_max, self.beta_max))
                    x_new = x_new + beta * _perp(u)
                    x_old = x_old + beta * _perp(self._u)
                    step = (x_new - x_old) / dt
        self._history.append(step)
        r = self.region
        self._x = np.array([min(max(x_new[0], r.xmin), r.xmax), min(max(x_new[1], r.ymin), r.ymax)])
        if self.velocity == "heading":
            self._v = float(np.mean([h @ u for h in self._history])) * u
        elif self.velocity == "mean":
            self._v = np.mean(self._history, axis=0)
        else:
            self._v = step
        self._u, self._t = u, t
        return self._emit(t)

    def _emit(self, t: float) -> VelocityEstimate:
        return VelocityEstimate(t=t, method=self.name, vx=float(self._v[0]), vy=float(self._v[1]),
                                x=float(self._x[0]), y=float(self._x[1]))


MOTION_TRACKERS = {
    cls.name: cls for cls in (VelocityPlaneTracker, SvmTracker, PprTracker, MotionRandomWalkTracker)
}
