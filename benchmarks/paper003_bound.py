"""Paper 003 on simulated testbeds: every pass's error beside the lower bounds on it.

Per testbed (``bintrack simulate laser-testbed --seed S --jitter J --passes N --lean 63 --offset 0.2``
unless told otherwise) and per pass: the entry and exit errors (ft) of the tracker's online
estimate (its first, ``bintrack track --online``: the re-solve at the pass's close) and of its
final one (the latest revision, ``bintrack track``), beside

* **known**: the bound with the beams known exactly, the pass's own geometry
  (``pass_bound.known_beams_bound``);
* **unknown, online**: the bound with the beams estimated jointly from passes 1 … this one
  (calibration passes and light-sensor positions known, as the tracker has them);
* **unknown, final**: the same from every pass of the testbed.

Bounds are √trace of the entry/exit covariance bound (the RMS error of an efficient estimator),
for timing noise of variance J²/3 (see ``pass_bound``'s docstring for why not the uniform's own).
Imported by ``benchmarks/paper003.py`` (``--bound``).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

FIRST_SCORED = 5
BOX = (0.0, 0.0, 16.0, 8.0)


def bound_run(job: tuple) -> dict:
    """One testbed: per pass (from pass 1) online and final entry/exit errors, the three bounds,
    and seconds per pass (the tracker's work when a pass completes, revisions included)."""
    from bintrack.evaluation.metrics import entry_exit_errors, truth_paths
    from bintrack.formats import open_dataset, write_dataset
    from bintrack.pipeline import output_objects, run_tracker
    from bintrack.sim.scenarios import build_scenario, simulate
    from bintrack.trackers.laser.pass_bound import known_beams_bound, unknown_beams_bounds
    from bintrack.trackers.laser.tracker import AdaptiveBasisTracker

    seed, jitter, passes, lean, offset, *rest = job
    revise = rest[0] if rest else True
    options = {"passes": passes, "jitter": jitter, "lean": lean, "offset": offset}
    scenario = build_scenario("laser-testbed", seed, **options)
    lines = np.array([(s.a, s.b) for s in scenario.sensors])
    positions = {k: (s.x, s.y) for k, s in enumerate(scenario.sensors)}
    segs = [t.segments[0] for t in scenario.trajectories]
    truth_w = np.array([[s.vx, s.x0, s.vy, s.y0] for s in segs])
    refs = [s.t0 for s in segs]
    known = np.array([known_beams_bound(lines, truth_w[l], refs[l], BOX, jitter) for l in range(passes)])
    final = unknown_beams_bounds(lines, truth_w, refs, BOX, jitter, known=(0, 1), positions=positions)
    online = np.array([unknown_beams_bounds(lines, truth_w[:l + 1], refs[:l + 1], BOX, jitter, known=(0, 1),
                                            positions=positions)[l] for l in range(passes)])
    sim = simulate("laser-testbed", seed, **options)
    with tempfile.TemporaryDirectory() as tmp:
        dataset = open_dataset(write_dataset(Path(tmp), sim.deployment, sim.events, sim.truth))
        tracker = AdaptiveBasisTracker(dataset.deployment, revise=revise)
        seconds, at_close = [], {}
        close = tracker._close

        def timed_close():
            started = time.perf_counter()
            out = close()
            seconds.append(time.perf_counter() - started)
            first = {o.object for o in out if o.revision is None}
            at_close.update({o.object: o for o in out if o.object in first})
            return out

        tracker._close = timed_close
        outputs = list(run_tracker(dataset, tracker))
        paths = truth_paths(dataset.truth())
    errors = {}
    for kind, rows in (("online", output_objects(outputs, online=True)), ("final", output_objects(outputs)),
                       ("at_close", output_objects(at_close.values()))):
        err = np.full((passes, 2), np.nan)
        for e in entry_exit_errors(rows, paths):
            err[e.object - 1] = (e.entry, e.exit)
        errors[kind] = err
    revisions = sum(1 for o in outputs if getattr(o, "revision", None))
    return {"seed": seed, "online": errors["online"], "final": errors["final"], "at_close": errors["at_close"],
            "known": known,
            "unknown_online": online, "unknown_final": final, "seconds": np.array(seconds), "revisions": revisions}


def summarise(results: list[dict], label: str) -> dict:
    """Print means ± sd over testbeds (each testbed: the mean of its passes from
    :data:`FIRST_SCORED` on) of the errors and bounds, the ratios, the worst pass and the worst
    testbed; return the figures."""
    s = slice(FIRST_SCORED - 1, None)
    keys = ("online", "at_close", "final", "known", "unknown_online", "unknown_final")
    per = {k: np.array([np.nanmean(r[k][s], axis=0) for r in results]) for k in keys}  # testbeds × 2
    worst = {k: np.array([np.nanmax(r[k][s], axis=0) for r in results]) for k in ("online", "at_close", "final")}
    print(f"\n{label}: {len(results)} testbeds, passes {FIRST_SCORED}..{results[0]['online'].shape[0]}; "
          "per testbed the mean over its passes, then mean ± sd over testbeds (ft)")
    print(f"{'':28}{'entry':>18}{'exit':>18}")
    for k, text in (("online", "ours, online (first)"), ("at_close", "ours, at close (latest then)"),
                    ("final", "ours, final (latest revision)"),
                    ("known", "bound, beams known"), ("unknown_online", "bound, beams from passes so far"),
                    ("unknown_final", "bound, beams from all passes")):
        cells = [f"{per[k][:, i].mean():.3f} ± {per[k][:, i].std(ddof=1):.3f}" for i in (0, 1)]
        print(f"{text:28}{cells[0]:>18}{cells[1]:>18}")
    ratio = {k: per[k].mean(0) / per["known"].mean(0) for k in ("online", "final", "unknown_final")}
    for k, text in (("final", "final / known bound"), ("online", "online / known bound"),
                    ("unknown_final", "all-passes bound / known")):
        print(f"{text:28}{ratio[k][0]:>18.2f}{ratio[k][1]:>18.2f}")
    print(f"{'worst pass, final':28}{worst['final'][:, 0].max():>18.3f}{worst['final'][:, 1].max():>18.3f}")
    print(f"{'worst pass, online':28}{worst['online'][:, 0].max():>18.3f}{worst['online'][:, 1].max():>18.3f}")
    print(f"{'worst pass, at close':28}{worst['at_close'][:, 0].max():>18.3f}{worst['at_close'][:, 1].max():>18.3f}")
    print(f"{'worst testbed mean, at close':28}{per['at_close'][:, 0].max():>18.3f}{per['at_close'][:, 1].max():>18.3f}")
    print(f"{'worst testbed mean, online':28}{per['online'][:, 0].max():>18.3f}{per['online'][:, 1].max():>18.3f}")
    print(f"{'worst testbed mean, final':28}{per['final'][:, 0].max():>18.3f}{per['final'][:, 1].max():>18.3f}")
    print(f"revisions published: {np.mean([r['revisions'] for r in results]):.1f} per testbed on average")
    return {"per": per, "worst": worst, "ratio": ratio}


def print_passes(result: dict) -> None:
    """One testbed, pass by pass: errors, bounds and ratios (entry / exit, ft)."""
    print(f"\nseed {result['seed']}, pass by pass (entry / exit, ft): ours online, ours final, bounds: beams known, "
          "beams from passes so far, from all passes; final / known")
    for l in range(result["online"].shape[0]):
        row = [result[k][l] for k in ("online", "final", "known", "unknown_online", "unknown_final")]
        cells = " ".join(f"{a:6.3f}/{b:<6.3f}" for a, b in row)
        ratio = result["final"][l] / result["known"][l]
        print(f"{l + 1:>4} {cells} {ratio[0]:5.2f}/{ratio[1]:<5.2f}")


def print_by_pass_range(results: list[dict]) -> None:
    """Entry error (mean over testbeds and the passes of a range) of the online, at-close and
    final estimates beside the bounds: how many passes the estimates need to near the bound."""
    n = results[0]["online"].shape[0]
    edges = [e for e in (FIRST_SCORED, 9, 13, 21, 29) if e <= n] + [n + 1]
    print("entry error by passes (ft, mean over testbeds and passes): ours online / at close / final; "
          "bounds: beams from passes so far / from all passes / known; online ÷ bound so far")
    for lo, hi in zip(edges, edges[1:]):
        s = slice(lo - 1, hi - 1)
        v = [np.nanmean([r[k][s, 0] for r in results]) for k in
             ("online", "at_close", "final", "unknown_online", "unknown_final", "known")]
        print(f"  passes {lo:>2}–{hi - 1:<2} " + " / ".join(f"{x:.3f}" for x in v[:3]) + "   "
              + " / ".join(f"{x:.3f}" for x in v[3:]) + f"   {v[0] / v[3]:.2f}")


def passes_near_bound(results: list[dict], kind: str = "online", factor: float = 1.5) -> int | None:
    """The first pass number from which the entry error of ``kind`` (online, at_close), averaged
    over testbeds, stays within ``factor`` × the bound with the beams from the passes so far."""
    err = np.nanmean([r[kind][:, 0] for r in results], axis=0)
    bound = np.nanmean([r["unknown_online"][:, 0] for r in results], axis=0)
    ok = err <= factor * bound
    for l in range(FIRST_SCORED - 1, len(ok)):
        if ok[l:].all():
            return l + 1
    return None


def scaling(pool, passes: int, jitter: float = 0.02) -> None:
    """Seconds per pass (median by range of pass numbers) on one long testbed, with the
    revisions and without them (phases 1–3 alone: the tracker before revisions)."""
    runs = list(pool.map(bound_run, [(1, jitter, passes, 63.0, 0.2, revise) for revise in (True, False)]))
    chunks = np.array_split(np.arange(FIRST_SCORED - 1, passes), 5)
    print(f"\ntime per pass, one testbed of {passes} passes, seed 1, in one run (median ms by range of passes):")
    print(f"{'passes':>22}" + "".join(f"{f'{c[0] + 1}–{c[-1] + 1}':>10}" for c in chunks))
    for r, label in zip(runs, ("with revisions", "phases 1–3 only")):
        print(f"{label:>22}" + "".join(f"{np.median(r['seconds'][c]) * 1e3:>10.1f}" for c in chunks))
    ratio = [np.median(runs[0]["seconds"][c]) / np.median(runs[1]["seconds"][c]) for c in chunks]
    print(f"{'ratio':>22}" + "".join(f"{x:>10.2f}" for x in ratio))
