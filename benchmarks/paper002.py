"""Paper 002 (closer/farther sensors): the MSE curves of the SVM and PPR velocity estimators
against the number of sensors, and the random-walk tracker's position and velocity MSE over time.

Setting (paper 002 §V, DESIGN §8.5; the paper's numbers were lost from our copy, see
docs/paper002.md): the ``motion`` scenario — N closer/farther sensors uniform on a 300 m × 300 m
field, every sensor reporting ±1 each period P = 1 s.

* Part 1 (paper Fig. "sim_conv"): a constant-velocity target at 2 m/s in a random direction
  for 100 s inside the central 240 m square; N = 10, 20, …, 100; ``--runs`` runs (seeds) per N.
  Each estimator sees the whole run (the paper's batch estimation) and we report the MSE of the
  heading (rad²) and of the speed ((m/s)²) with 95 % CIs, the SVM and PPR side by side (and the
  velocity plane fit, an extra), and the share of runs where an estimator had no answer.
* Part 2 (paper Figs. "traj_est" and "mse_state"): the ``motion-rw`` tracker on the scenario's
  random walk (100 sensors, 2 m/s, velocity noise σ = 0.1 m/s per period, 100 s),
  ``--rw-runs`` runs; position MSE (m²) and velocity MSE ((m/s)²) against time.
* Part 3: the window of the velocity trackers online on the random walk: all periods so far
  (the default, the paper's batch) against the last 10 (``--window-runs`` runs).
* Acceptance: the four trackers (the objects ``bintrack track`` runs) on full simulated event
  streams (transition detector → tracker) with 100 sensors and a constant velocity: heading and
  speed error of their last estimate over ``--online-runs`` runs.

Per run the work is pure numpy: the label matrix (K periods × N sensors) is computed from the
scenario's trajectory exactly as the simulator's motion model does (sign of (s − x)·v at the
sample times), and the estimators of ``bintrack.trackers.motion`` run on it; Part 2 and the
acceptance feed the trackers transitions made from the same labels (the acceptance through the
simulator's events and the offline driver). Progress goes to stderr.

Run: ``nice -n 5 .venv/bin/python benchmarks/paper002.py`` (≈ 8 min on 2 cores);
``--quick`` for a 1-minute smoke run.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from bintrack.evaluation.metrics import mean_ci

NODES = tuple(range(10, 101, 10))
SPEED = 2.0  # m/s
DURATION = 100.0  # s
PERIOD = 1.0  # s
RW_NODES = 100
ESTIMATORS = ("svm", "ppr", "velocity-plane")
TRACKERS = ("velocity-plane", "svm", "ppr", "motion-rw")


# --------------------------------------------------------------------------- per-run work


def labels_of(scenario):
    """(positions (N, 2) m, labels (K, N) ±1, times (K,) s, true positions (K, 2), true
    velocities (K, 2)) of a motion scenario: the simulator's samples at k·P within the
    target's life, +1 where (s − x)·v > 0 (bintrack.sensing.MotionModel)."""
    from bintrack.sim.sampling import sample_times

    path = scenario.trajectories[0]
    positions = np.array([(s.x, s.y) for s in scenario.sensors])
    times = sample_times(0.0, scenario.sensors[0].period, *scenario.window)
    times = times[path.alive(times)]
    x, v = path.position(times), path.velocity(times)
    closing = ((positions[None, :, :] - x[:, None, :]) * v[:, None, :]).sum(axis=2)
    return positions, np.where(closing > 0.0, 1, -1), times, x, v


def _angle(a: float, b: float) -> float:
    return (a - b + math.pi) % (2 * math.pi) - math.pi


def estimator_runs(job: tuple[int, list[int]]) -> tuple[int, dict[str, list[tuple[float, float] | None]]]:
    """Part 1 for one N and some seeds: per estimator, (heading error rad, speed error m/s) or None."""
    from bintrack.trackers.motion.ppr_estimator import ppr_fit
    from bintrack.trackers.motion.svm_estimator import svm_velocity
    from bintrack.trackers.motion.velocity_plane import velocity_plane
    from bintrack.sim.scenarios import build_scenario

    nodes, seeds = job
    out: dict[str, list] = {name: [] for name in ESTIMATORS}
    for seed in seeds:
        scenario = build_scenario("motion", seed, nodes=nodes, trajectory="constant", speed=SPEED,
                                  duration=DURATION, period=PERIOD)
        positions, labels, times, _, v = labels_of(scenario)
        heading, speed = math.atan2(v[0, 1], v[0, 0]), math.hypot(*v[0])
        fits = {"svm": svm_velocity(positions, labels, times),
                "ppr": ppr_fit(positions, labels, PERIOD),
                "velocity-plane": velocity_plane(positions, labels, PERIOD)}
        for name, fit in fits.items():
            out[name].append(None if fit is None else (_angle(fit.heading, heading), fit.speed - speed))
    return nodes, out


def _transitions(ids: list[str], labels: np.ndarray, times: np.ndarray):
    """The transitions a sensor agent publishes for these samples (idle value −1)."""
    from bintrack.bus_payloads import Transition

    previous = np.full(labels.shape[1], -1)
    seq = np.zeros(labels.shape[1], dtype=int)
    for k, t in enumerate(times):
        for i in np.flatnonzero(labels[k] != previous):
            seq[i] += 1
            yield Transition(t=float(t), sensor=ids[i], value=int(labels[k, i]), previous=int(previous[i]),
                             seq=int(seq[i]))
        previous = labels[k]


def rw_runs(seeds: list[int]) -> list[tuple[np.ndarray, np.ndarray, np.ndarray | None]]:
    """Part 2: per seed, squared position and velocity errors by period (NaN where no estimate),
    and for the first seed the true and estimated paths (for the example plot)."""
    from bintrack.sim.scenarios import build_scenario
    from bintrack.trackers.motion.tracker import MotionRandomWalkTracker

    results = []
    for seed in seeds:
        scenario = build_scenario("motion", seed, nodes=RW_NODES, trajectory="random-walk", speed=SPEED,
                                  duration=DURATION, period=PERIOD)
        positions, labels, times, x, v = labels_of(scenario)
        tracker = MotionRandomWalkTracker(scenario.deployment)
        out = []
        for transition in _transitions([s.id for s in scenario.sensors], labels, times):
            out.extend(tracker.update(transition))
        out.extend(tracker.flush(math.inf))
        k_max = int(round(DURATION / PERIOD)) + 1
        pos_err, vel_err = np.full(k_max, np.nan), np.full(k_max, np.nan)
        index = {round(t / PERIOD): k for k, t in enumerate(times)}
        example = np.full((k_max, 4), np.nan)
        for e in out:
            k = index[round(e.t / PERIOD)]
            pos_err[k] = (e.x - x[k, 0]) ** 2 + (e.y - x[k, 1]) ** 2
            vel_err[k] = (e.vx - v[k, 0]) ** 2 + (e.vy - v[k, 1]) ** 2
            example[k] = (x[k, 0], x[k, 1], e.x, e.y)
        results.append((pos_err, vel_err, example))
    return results


def online_runs(seeds: list[int]) -> dict[str, list[tuple[float, float] | None]]:
    """Acceptance: each tracker on the simulated event stream (100 sensors, constant velocity);
    (heading error rad, relative speed error) of its last estimate."""
    from bintrack.pipeline import TrackerDriver
    from bintrack.sim.scenarios import build_scenario, simulate
    from bintrack.trackers.motion.tracker import MOTION_TRACKERS
    from bintrack.transition_detector import TransitionDetector

    out: dict[str, list] = {name: [] for name in TRACKERS}
    for seed in seeds:
        options = dict(nodes=100, trajectory="constant", speed=SPEED, duration=DURATION, period=PERIOD)
        result = simulate("motion", seed, **options)
        path = build_scenario("motion", seed, **options).trajectories[0]
        for name in TRACKERS:
            detector = TransitionDetector(result.deployment)
            driver = TrackerDriver(MOTION_TRACKERS[name](result.deployment))
            estimates = []
            for event in result.events:
                transition = detector.update(event)
                if transition is not None:
                    estimates.extend(driver.advance(transition.t))
                    driver.push(transition)
            estimates.extend(driver.finish())
            if not estimates:
                out[name].append(None)
                continue
            last = estimates[-1]
            v = path.velocity(np.array([last.t]))[0]
            out[name].append((_angle(math.atan2(last.vy, last.vx), math.atan2(v[1], v[0])),
                              math.hypot(last.vx, last.vy) / math.hypot(*v) - 1.0))
    return out


WINDOWS = (None, 10)


def window_runs(seeds: list[int]) -> dict[tuple[str, int | None], list[tuple[float, float]]]:
    """Part 3: the three velocity trackers online on the random walk, all periods so far
    (window None) against the last 10: per run, the RMS heading error (rad) and velocity error
    (m/s) of the estimates from t = 20 s on."""
    from bintrack.sim.scenarios import build_scenario
    from bintrack.trackers.motion.tracker import MOTION_TRACKERS

    out: dict[tuple[str, int | None], list] = {}
    for seed in seeds:
        scenario = build_scenario("motion", seed, nodes=RW_NODES, trajectory="random-walk", speed=SPEED,
                                  duration=DURATION, period=PERIOD)
        positions, labels, times, x, v = labels_of(scenario)
        transitions = list(_transitions([s.id for s in scenario.sensors], labels, times))
        index = {round(t / PERIOD): k for k, t in enumerate(times)}
        for name in ("velocity-plane", "svm", "ppr"):
            for window in WINDOWS:
                if name == "svm" and window is None:
                    continue  # a soft margin over every period of a random walk: slow and meaningless
                tracker = MOTION_TRACKERS[name](scenario.deployment, window=window)
                estimates = []
                for transition in transitions:
                    estimates.extend(tracker.update(transition))
                estimates.extend(tracker.flush(math.inf))
                h, e = [], []
                for est in estimates:
                    k = index[round(est.t / PERIOD)]
                    if est.t >= 20.0:
                        h.append(_angle(math.atan2(est.vy, est.vx), math.atan2(v[k, 1], v[k, 0])))
                        e.append(math.hypot(est.vx - v[k, 0], est.vy - v[k, 1]))
                if h:
                    out.setdefault((name, window), []).append((float(np.sqrt(np.mean(np.square(h)))),
                                                               float(np.sqrt(np.mean(np.square(e))))))
    return out


# --------------------------------------------------------------------------- driver


def _chunks(seeds: list[int], size: int) -> list[list[int]]:
    return [seeds[i:i + size] for i in range(0, len(seeds), size)]


def _progress(label: str, done: int, total: int, started: float) -> None:
    print(f"\r{label}: {done}/{total} ({time.monotonic() - started:.0f} s)", end="", file=sys.stderr, flush=True)


def _mse(values: list[float]) -> tuple[float, float]:
    return mean_ci(np.square(values))


def part1(runs: int, jobs: int) -> dict[int, dict[str, list]]:
    work = [(n, chunk) for n in NODES for chunk in _chunks(list(range(runs)), 25)]
    results: dict[int, dict[str, list]] = {n: {name: [] for name in ESTIMATORS} for n in NODES}
    started = time.monotonic()
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        for done, (n, out) in enumerate(pool.map(estimator_runs, work), start=1):
            for name in ESTIMATORS:
                results[n][name].extend(out[name])
            _progress("part 1 (estimators vs N)", done * 25, len(work) * 25, started)
    print(file=sys.stderr)
    return results


def print_part1(results: dict[int, dict[str, list]], runs: int) -> None:
    print(f"\nPart 1 — batch velocity estimation, constant velocity {SPEED:g} m/s, {DURATION:g} s, P = {PERIOD:g} s, "
          f"300 m × 300 m, {runs} runs per N (mean ± 95 % CI; 'none' = runs without an estimate)")
    print("paper (Fig. sim_conv; curves only, values lost): direction — PPR much better than SVM and stable in N; "
          "speed — only SVM reasonable, from N ≈ 60")
    head = f"{'N':>4} | {'heading MSE (rad²)':^49} | {'speed MSE ((m/s)²)':^49} | none svm/ppr/vp"
    print(head)
    print(f"{'':>4} | {'SVM':^16}{'PPR':^16}{'plane':^17} | {'SVM':^16}{'PPR':^16}{'plane':^17} |")
    print("-" * len(head))
    for n in NODES:
        cells_h, cells_s, nones = [], [], []
        for name in ESTIMATORS:
            ok = [r for r in results[n][name] if r is not None]
            nones.append(str(len(results[n][name]) - len(ok)))
            if len(ok) >= 2:
                m, h = _mse([a for a, _ in ok])
                cells_h.append(f"{m:.2e}±{h:.0e}".center(16))
                m, h = _mse([s for _, s in ok])
                cells_s.append(f"{m:.2e}±{h:.0e}".center(16))
            else:
                cells_h.append("-".center(16))
                cells_s.append("-".center(16))
        print(f"{n:>4} | {''.join(cells_h)} | {''.join(cells_s)} | {'/'.join(nones)}")
    print("\nSame runs, robust view: median |heading error| (deg) and median |speed error| (% of 2 m/s)")
    print(f"{'N':>4} | {'SVM':>8} {'PPR':>8} {'plane':>8} | {'SVM':>8} {'PPR':>8} {'plane':>8}")
    for n in NODES:
        row_h, row_s = [], []
        for name in ESTIMATORS:
            ok = [r for r in results[n][name] if r is not None]
            row_h.append(f"{np.degrees(np.median(np.abs([a for a, _ in ok]))):8.3f}" if ok else f"{'-':>8}")
            row_s.append(f"{100 * np.median(np.abs([s for _, s in ok])) / SPEED:8.3f}" if ok else f"{'-':>8}")
        print(f"{n:>4} | {' '.join(row_h)} | {' '.join(row_s)}")


def part2(runs: int, jobs: int):
    work = _chunks(list(range(runs)), 10)
    collected = []
    started = time.monotonic()
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        for done, out in enumerate(pool.map(rw_runs, work), start=1):
            collected.extend(out)
            _progress("part 2 (random-walk tracker)", min(done * 10, runs), runs, started)
    print(file=sys.stderr)
    pos = np.array([p for p, _, _ in collected])
    vel = np.array([v for _, v, _ in collected])
    return pos, vel, collected[0][2]


def _curve(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    means, halves = [], []
    for column in values.T:
        ok = column[np.isfinite(column)]
        m, h = mean_ci(ok) if len(ok) else (np.nan, np.nan)
        means.append(m)
        halves.append(h)
    return np.array(means), np.array(halves)


def print_part2(pos: np.ndarray, vel: np.ndarray, runs: int) -> None:
    pm, ph = _curve(pos)
    vm, vh = _curve(vel)
    print(f"\nPart 2 — random-walk tracker (motion-rw), {RW_NODES} sensors, 300 m × 300 m, {DURATION:g} s, {runs} runs "
          "(mean ± 95 % CI)")
    print("paper (Figs. traj_est, mse_state; values lost): example run follows within ≈ 10 m after the first step "
          "(placeholder read as 10, see docs); both MSEs drop sharply in the first seconds, then level off above 0")
    print(f"{'t (s)':>6} | {'position MSE (m²)':>22} | {'position RMSE (m)':>17} | {'velocity MSE ((m/s)²)':>22} | "
          f"{'velocity RMSE (m/s)':>19}")
    for t in (0, 1, 2, 5, 10, 20, 30, 40, 50, 60, 70, 80, 90, 99):
        if t < len(pm):
            print(f"{t:>6} | {pm[t]:>12.1f} ± {ph[t]:<7.1f} | {math.sqrt(pm[t]):>17.1f} | {vm[t]:>12.3f} ± {vh[t]:<7.3f} | "
                  f"{math.sqrt(vm[t]):>19.3f}")
    late = slice(50, None)
    print(f"mean over t ≥ 50 s: position RMSE {math.sqrt(np.nanmean(pos[:, late])):.1f} m, "
          f"velocity RMSE {math.sqrt(np.nanmean(vel[:, late])):.2f} m/s")


def part3(runs: int, jobs: int) -> dict:
    collected: dict = {}
    started = time.monotonic()
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        for done, out in enumerate(pool.map(window_runs, _chunks(list(range(runs)), 1)), start=1):
            for key, values in out.items():
                collected.setdefault(key, []).extend(values)
            _progress("part 3 (windows on the random walk)", done, runs, started)
    print(file=sys.stderr)
    print(f"\nPart 3 — online velocity trackers on the random walk ({RW_NODES} sensors, {runs} runs, estimates "
          "from t = 20 s): window = all periods so far (default) against the last 10 periods")
    print(f"{'tracker':>16} {'window':>7} | {'RMS heading error (deg)':>25} | {'RMS velocity error (m/s)':>25}")
    for name in ("velocity-plane", "svm", "ppr"):
        for window in WINDOWS:
            values = collected.get((name, window))
            if not values:
                continue
            mh, hh = mean_ci([np.degrees(a) for a, _ in values])
            mv, hv = mean_ci([b for _, b in values])
            print(f"{name:>16} {str(window if window else 'all'):>7} | {mh:>15.2f} ± {hh:<7.2f} | {mv:>15.3f} ± {hv:<7.3f}")
    return collected


def print_acceptance(part1_results: dict[int, dict[str, list]], online: dict[str, list]) -> None:
    print("\nAcceptance — 100 sensors, constant velocity (heading error < 5° and speed error < 10 % for the best):")
    print(f"{'estimator':>16} | {'RMS heading (deg)':>17} {'95th pct (deg)':>14} | {'RMS speed (%)':>13} "
          f"{'95th pct (%)':>12} | none")
    best = None
    for name in ESTIMATORS:
        ok = [r for r in part1_results[100][name] if r is not None]
        h = np.degrees(np.abs([a for a, _ in ok]))
        s = 100 * np.abs([b for _, b in ok]) / SPEED
        rms_h, rms_s = float(np.sqrt(np.mean(h ** 2))), float(np.sqrt(np.mean(s ** 2)))
        print(f"{'batch ' + name:>16} | {rms_h:>17.3f} {np.percentile(h, 95):>14.3f} | {rms_s:>13.3f} "
              f"{np.percentile(s, 95):>12.3f} | {len(part1_results[100][name]) - len(ok)}")
        if best is None or rms_h + rms_s < best[1] + best[2]:
            best = (name, rms_h, rms_s)
    for name in TRACKERS:
        ok = [r for r in online[name] if r is not None]
        if not ok:
            print(f"{'online ' + name:>16} | no estimates")
            continue
        h = np.degrees(np.abs([a for a, _ in ok]))
        s = 100 * np.abs([b for _, b in ok])
        print(f"{'online ' + name:>16} | {np.sqrt(np.mean(h ** 2)):>17.3f} {np.percentile(h, 95):>14.3f} | "
              f"{np.sqrt(np.mean(s ** 2)):>13.3f} {np.percentile(s, 95):>12.3f} | {len(online[name]) - len(ok)}")
    name, rms_h, rms_s = best
    verdict = "PASS" if rms_h < 5.0 and rms_s < 10.0 else "FAIL"
    print(f"best estimator: {name}: RMS heading error {rms_h:.3f}° (< 5°), RMS speed error {rms_s:.3f} % (< 10 %): {verdict}")


def plot(part1_results, pos, vel, example, runs, rw_runs_count, out_mse: Path, out_rw: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5), layout="constrained")
    styles = {"svm": ("C0", "-", "o"), "ppr": ("C1", "-", "s"), "velocity-plane": ("C2", "--", "^")}
    for ax, which, label in ((axes[0], 0, "heading MSE (rad²)"), (axes[1], 1, "speed MSE ((m/s)²)")):
        for name in ESTIMATORS:
            mci = [_mse([r[which] for r in part1_results[n][name] if r is not None]) for n in NODES]
            colour, line, marker = styles[name]
            ax.errorbar(NODES, [m for m, _ in mci], yerr=[h for _, h in mci], color=colour, linestyle=line,
                        marker=marker, capsize=3, label=name.upper() if name != "velocity-plane" else "velocity plane (extra)")
        ax.set_yscale("log")
        ax.set_xlabel("number of sensors N")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize="small")
    axes[0].set_title(f"direction, {runs} runs per N")
    axes[1].set_title(f"speed ({SPEED:g} m/s), {runs} runs per N")
    out_mse.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_mse, dpi=110)

    fig, axes = plt.subplots(1, 3, figsize=(16, 4.6), layout="constrained")
    t = np.arange(pos.shape[1]) * PERIOD
    for ax, values, label in ((axes[1], pos, "position MSE (m²)"), (axes[2], vel, "velocity MSE ((m/s)²)")):
        m, h = _curve(values)
        ax.plot(t, m, color="C3")
        ax.fill_between(t, m - h, m + h, color="C3", alpha=0.25, label="mean ± 95 % CI")
        ax.set_yscale("log")
        ax.set_xlabel("time (s)")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize="small")
        ax.set_title(f"motion-rw, {RW_NODES} sensors, {rw_runs_count} runs")
    ok = np.isfinite(example).all(axis=1)
    axes[0].plot(example[ok, 0], example[ok, 1], color="C3", label="true trajectory")
    axes[0].plot(example[ok, 2], example[ok, 3], color="C2", marker=".", label="estimate")
    axes[0].plot(example[ok, 0][:1], example[ok, 1][:1], "k*", label="start")
    axes[0].set_xlim(0, 300)
    axes[0].set_ylim(0, 300)
    axes[0].set_aspect("equal")
    axes[0].set_title("one run (seed 0)")
    axes[0].legend(fontsize="small")
    fig.savefig(out_rw, dpi=110)


def plot_staircase(out: Path) -> None:
    """The paper's first figure: the counters of one constant-velocity run (100 sensors) over
    the field, and against the sensors' projection on the true heading, with the fitted plane."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from bintrack.trackers.motion.closer_farther import counters
    from bintrack.trackers.motion.velocity_plane import velocity_plane
    from bintrack.sim.scenarios import build_scenario

    scenario = build_scenario("motion", 0, nodes=100, trajectory="constant", speed=SPEED, duration=DURATION,
                              period=PERIOD)
    positions, labels, times, x, v = labels_of(scenario)
    count = counters(labels)
    fit = velocity_plane(positions, labels, PERIOD)
    u = v[0] / np.hypot(*v[0])
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8), layout="constrained")
    sc = axes[0].scatter(positions[:, 0], positions[:, 1], c=count, cmap="viridis", s=30)
    axes[0].plot(x[:, 0], x[:, 1], color="C3", label="target")
    axes[0].set_xlim(0, 300)
    axes[0].set_ylim(0, 300)
    axes[0].set_aspect("equal")
    axes[0].legend(fontsize="small")
    axes[0].set_title("counters (+1 periods) of 100 sensors, seed 0")
    fig.colorbar(sc, ax=axes[0], label="counter")
    p = positions @ u
    axes[1].step(np.sort(p), np.sort(count), where="post", color="0.6", label="staircase (sorted)")
    axes[1].scatter(p, count, s=14, color="C0", label="sensors")
    grid = np.linspace(p.min(), p.max(), 200)
    slope = 1.0 / (fit.speed * PERIOD)
    offset = np.median(count[(count > 0) & (count < len(times))] - slope * p[(count > 0) & (count < len(times))])
    axes[1].plot(grid, np.clip(slope * grid + offset, 0, len(times)), color="C3",
                 label=f"velocity plane: {fit.speed:.3f} m/s, heading error "
                       f"{np.degrees(abs(_angle(fit.heading, math.atan2(u[1], u[0])))):.2f}°")
    axes[1].set_xlabel("projection of the sensor on the true heading (m)")
    axes[1].set_ylabel("counter")
    axes[1].legend(fontsize="small")
    fig.savefig(out, dpi=110)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=500, help="runs per number of sensors, part 1 (default: %(default)s)")
    parser.add_argument("--rw-runs", type=int, default=300, help="random-walk tracker runs, part 2 (default: %(default)s)")
    parser.add_argument("--online-runs", type=int, default=20, help="full-pipeline runs per tracker (default: %(default)s)")
    parser.add_argument("--window-runs", type=int, default=10, help="random-walk runs of part 3 (default: %(default)s)")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes (default: %(default)s)")
    parser.add_argument("--quick", action="store_true", help="a smoke run: 30 / 20 / 2 / 4 runs")
    parser.add_argument("--plot-mse", type=Path, default=Path("docs/paper002_mse.png"))
    parser.add_argument("--plot-rw", type=Path, default=Path("docs/paper002_rw.png"))
    parser.add_argument("--plot-staircase", type=Path, default=Path("docs/paper002_staircase.png"))
    args = parser.parse_args()
    if args.quick:
        args.runs, args.rw_runs, args.online_runs, args.window_runs = 30, 20, 4, 2
    for flag in ("runs", "rw_runs", "online_runs", "window_runs", "jobs"):
        if getattr(args, flag) < (2 if flag != "jobs" else 1):
            parser.error(f"--{flag.replace('_', '-')} is too small")
    started = time.monotonic()
    results = part1(args.runs, args.jobs)
    print_part1(results, args.runs)
    pos, vel, example = part2(args.rw_runs, args.jobs)
    print_part2(pos, vel, args.rw_runs)
    part3(args.window_runs, args.jobs)
    t0 = time.monotonic()
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        online: dict[str, list] = {name: [] for name in TRACKERS}
        chunks = _chunks(list(range(1000, 1000 + args.online_runs)), 2)
        for done, out in enumerate(pool.map(online_runs, chunks), start=1):
            for name in TRACKERS:
                online[name].extend(out[name])
            _progress("acceptance (full pipeline)", min(2 * done, args.online_runs), args.online_runs, t0)
    print(file=sys.stderr)
    print_acceptance(results, online)
    plot(results, pos, vel, example, args.runs, args.rw_runs, args.plot_mse, args.plot_rw)
    plot_staircase(args.plot_staircase)
    print(f"\nplots: {args.plot_mse}, {args.plot_rw}, {args.plot_staircase}; total {time.monotonic() - started:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
