"""Multi-target tracking on a family of simulated grids: our MCMCDA against tuned Stone Soup.

Issue 21. The suite is ``bintrack simulate darpa-grid`` with its settings varied per grid
(drawn once from a fixed seed, printed at the start):

* 2–10 people entering 4–8 s apart (``--people``, ``--entry-gap``);
* per-sample pd 0.6–0.9 and pfa 0.02–0.1 (``--pd``, ``--pfa``);
* walks straight or curving — heading a mean-reverting random walk around the course, 3 in 4
  grids (``--walk curving``);
* 1 to all possible crossing pairs (``--crossings``), 0–1 side-by-side pairs 2–5 m apart
  (``--pairs``), 0–2 people who stop for 5–15 s (``--stops``);
* 0–12 dead nodes (``--dead``), node jitter ±0–1 m (``--node-jitter``);
* the 12 × 12 grid at 5 m, 8 m range, 0.5 s period of paper 004.

It is split into a **tuning half** and a **held-out half** (fixed, different simulation seeds,
the same mix of settings). On each grid:

* ours (``bintrack track DIR --tracker mcmcda``: grid fusion + online MCMCDA, its defaults)
  runs with sampler seeds 0..S−1 (``--mcmc-seeds``);
* Stone Soup GNN and JPDA (``benchmarks/mcmcda_vs_stonesoup.py``: same fused reports without
  track aid, same constant-velocity model) run on the tuning half over a small grid of their
  settings — initiator min_points 2–4 × deleter (2, 3, 5 missed scans or covariance trace
  > 20 m²) at the first gate, then the other gate at the best, then (JPDA) its pd of a report
  ∈ {0.5, 0.6, 0.7} besides ours, then the best with its own process noise q ∈ {0.01, 0.05,
  0.1, 0.2} m²/s³ besides ours — and the setting with the lowest mean GOSPA over the tuning
  half is scored on the held-out half;
* so are JIPDA, MFA and a labelled GM-PHD built from Stone Soup's parts
  (``benchmarks/stonesoup_peers.py``: the same input; a first grid over the pd each assumes,
  then one parameter at a time);
* the peers' input has the fusion's bars in fixed nats, as they were first tuned;
  ``--peer-bars scaled`` gives them ours, which grow with the sensors' evidence (docs/peers.md
  compares the two); so is its count of targets, over the union of the disks:
  ``--peer-multiplicity`` gives them ours, each target detected on its own;
* ``--conditions N``: N grids per row of harder conditions (``benchmarks/multi_conditions.py``),
  ours with its defaults beside each Stone Soup tracker with the setting chosen above.

Our defaults are chosen on the tuning half only (``--variant`` runs other settings of ours on
it). Scores as ``bintrack eval`` (``bintrack.evaluation.metrics.multi_target_scores``) at every scan from
the first entry to the last exit: GOSPA (c = 10 m, p = 2, α = 2) and its parts (m²), mean
|tracks − people|, identity switches (CLEAR MOT mismatches) and track ids summed over the
half, IDF1 (motmetrics, hit threshold 5 m), and ms per scan (ours: fusion + MCMCDA; Stone
Soup: its tracking step). The seed
spread of ours (its mean GOSPA over the half for each sampler seed) is printed beside the
spread of GNN's over its settings on the tuning half.

Simulated grids are cached under ``/tmp/bintrack-multi-target`` (``--cache``). Needs the
``bench`` extra (Stone Soup, ortools); exits 2 without it. Default run (8 + 8 grids, 3
sampler seeds, the five Stone Soup trackers' 88 settings on the tuning half): 40 min with one
worker (``--jobs 1``) on the 2-core machine beside another job; with GNN and JPDA alone
(``--stonesoup GNN --stonesoup JPDA``) it was 4.5 min on the idle machine with 2 workers.
``--conditions 3 --conditions-only --tuned FILE``: 20 min more. ``--quick`` (3 + 3 grids, 2
seeds, a few settings per tracker) is a few minutes. A Stone Soup setting is abandoned past 60 s
of wall time on one grid (or when Stone Soup's MFA finds no feasible assignment); its score is
kept under ``--cache`` so that a run cut short resumes (``--fresh``: run them again).
Progress on stderr, results on stdout.

Run: ``nice -n 10 .venv/bin/python benchmarks/multi_target.py [--quick] [--jobs 2] [--conditions 3]``
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
import itertools
import json
import multiprocessing
import sys
import time
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import numpy as np

from bench_support import DOCS
import mcmcda_vs_stonesoup as vs  # Stone Soup wiring and scoring shared with issue 6's benchmark (beside it)
import multi_conditions as conditions  # the harder conditions' rows (issue 42)
import stonesoup_peers as sp      # JIPDA, MFA, GM-PHD (issue 42)

SUITE_SEED = 2026
PEOPLE = (2, 3, 4, 5, 6, 7, 8, 10)
HALVES = {"tuning": 1000, "held-out": 2000}  # simulation seeds start here
DEFAULT_CACHE = Path("/tmp/bintrack-multi-target")
DEFAULT_PLOT = DOCS / "multi_target.png"
DEFAULT_CONDITIONS_PLOT = DOCS / "multi_conditions.png"
MIN_POINTS = (2, 3, 4)
PEER_PROCESS_NOISE = (0.01, 0.05, 0.1, 0.2)  # m²/s³, besides ours, for the peer's CV model
DELETERS = ("steps:2", "steps:3", "steps:5", "cov:20")
JPDA_PD = (0.5, 0.6, 0.7)  # besides our MCMCDA's 0.85
KINDS = ("GNN", "JPDA", *sp.PEERS)
QUICK_SETTINGS = {"GNN": [vs.Setting(3.0, m, d) for m, d in ((2, "steps:3"), (3, "steps:2"), (3, "steps:3"), (4, "steps:3"))],
                  "JPDA": [vs.Setting(0.99, m, d) for m, d in ((2, "steps:3"), (3, "steps:2"), (3, "steps:3"), (4, "steps:3"))],
                  **sp.QUICK}
say = vs.say


# --------------------------------------------------------------------------- the suite


def suite(per_half: int) -> dict[str, list[dict]]:
    """The grids' ``bintrack simulate darpa-grid`` options per half, drawn from SUITE_SEED.
    Both halves get the same people counts (shuffled); every other setting is drawn per grid."""
    from bintrack.sim.scenarios import ScenarioError, build_scenario

    rng = np.random.default_rng(SUITE_SEED)
    halves = {}
    for half, base in HALVES.items():
        counts = [PEOPLE[k % len(PEOPLE)] for k in range(per_half)]
        grids = []
        for i, people in enumerate(rng.permutation(counts)):
            people = int(people)
            spec = dict(seed=base + i, people=people, pd=round(float(rng.uniform(0.6, 0.9)), 2),
                        pfa=round(float(rng.uniform(0.02, 0.1)), 3),
                        walk="curving" if rng.random() < 0.75 else "straight",
                        entry_gap=round(float(rng.uniform(4.0, 8.0)), 1),
                        dead=int(rng.integers(0, 13)), node_jitter=round(float(rng.uniform(0.0, 1.0)), 2),
                        stops=int(rng.integers(0, min(2, people) + 1)))
            most = 1 if people < 4 else 1 + len(range(4, people, 2))
            spec["crossings"] = int(rng.integers(1, most + 1))
            spec["pairs"] = int(people >= 4 and rng.random() < 0.5)
            while True:  # fewer crossings (then pairs) until the people suffice
                try:
                    build_scenario("darpa-grid", spec["seed"], **{k: v for k, v in spec.items() if k != "seed"})
                    break
                except (ScenarioError, ValueError):
                    if spec["crossings"] > 1:
                        spec["crossings"] -= 1
                    else:
                        spec["pairs"] -= 1
            grids.append(spec)
        halves[half] = grids
    return halves


def command(spec: dict) -> str:
    flags = " ".join(f"--{k.replace('_', '-')} {v}" for k, v in spec.items())
    return f"bintrack simulate darpa-grid {flags}"


def dataset(spec: dict, cache: Path) -> Path:
    """The grid's dataset folder under ``cache``, simulated on first use."""
    from bintrack.formats import write_dataset
    from bintrack.sim import simulate

    folder = cache / "-".join(f"{k}{v}" for k, v in spec.items())
    if not (folder / "truth.csv").exists():
        sim = simulate("darpa-grid", spec["seed"], **{k: v for k, v in spec.items() if k != "seed"})
        tmp = folder.with_name(folder.name + ".part")
        write_dataset(tmp, sim.deployment, sim.events, sim.truth)
        tmp.rename(folder)
    return folder


# --------------------------------------------------------------------------- ours


VARIANTS: dict[str, dict] = {
    "default": {},
    "chains1": {"mcmcda": {"chains": 1}},
    "reid4": {"mcmcda": {"reidentify": 4.0}},
    "reid15": {"mcmcda": {"reidentify": 15.0}},
    "reid30": {"mcmcda": {"reidentify": 30.0}},
    "reid60": {"mcmcda": {"reidentify": 60.0}},
    "chains4": {"mcmcda": {"chains": 4}},
    "chains8": {"mcmcda": {"chains": 8}},
    "nmc2000": {"mcmcda": {"n_mc": 2000}},
    "min3": {"mcmcda": {"min_reports": 3}},
    "coast2": {"mcmcda": {"coast": 2}},
    "window8": {"mcmcda": {"window": 8}},
    "q0.3": {"mcmcda": {"process_noise": 0.3}},
    "q0.1": {"mcmcda": {"process_noise": 0.1}},
    "q0.07": {"mcmcda": {"process_noise": 0.07}},
    "q0.05": {"mcmcda": {"process_noise": 0.05}},
    "q0.03": {"mcmcda": {"process_noise": 0.03}},
    "q0.025": {"mcmcda": {"process_noise": 0.025}},
    "q0.015": {"mcmcda": {"process_noise": 0.015}},
    "q0.01": {"mcmcda": {"process_noise": 0.01}},
    "ev3": {"mcmcda": {"extra_variance": 3.0}},
    "initial1": {"mcmcda": {"initial_speed": 1.0}},
    "ev1": {"mcmcda": {"extra_variance": 1.0}},
    "ev9": {"mcmcda": {"extra_variance": 9.0}},
    "birth3e-4": {"mcmcda": {"birth_rate": 3e-4}},
    "expected0.5": {"fusion": {"expected_gain": 0.5}},
    "min_gain2": {"fusion": {"min_gain": 2.0}},
    "mg3": {"fusion": {"min_gain": 3.0}},
    "mg3.5": {"fusion": {"min_gain": 3.5}},
    "mg3.5e0.5": {"fusion": {"min_gain": 3.5, "expected_gain": 0.5}},
    "mg4.5": {"fusion": {"min_gain": 4.5}},
    "mg5": {"fusion": {"min_gain": 5.0}},
    "mg4e0.5": {"fusion": {"min_gain": 4.0, "expected_gain": 0.5}},
    "adapt50": {"mcmcda": {"adapt_rates": 50}},
    "adapt200": {"mcmcda": {"adapt_rates": 200}},
    "adapt1000": {"mcmcda": {"adapt_rates": 1000}},
    "noexit": {"mcmcda": {"exit_depth": None}},
    "evidence1.5": {"fusion": {"evidence_reference": 1.5}},
    "evidence1.6": {"fusion": {"evidence_reference": 1.6}},
    "evidence1.8": {"fusion": {"evidence_reference": 1.8}},
    "evidence1.9": {"fusion": {"evidence_reference": 1.9}},
    "noevidence": {"fusion": {"evidence_reference": None}},
    "exit0": {"mcmcda": {"exit_depth": 0.0}},
    "entry1": {"mcmcda": {"entry_depth": 1.0}},
    "entry2": {"mcmcda": {"entry_depth": 2.0}},
    "entry4": {"mcmcda": {"entry_depth": 4.0}},
    "entry2g8": {"mcmcda": {"entry_depth": 2.0, "entry_gain": 8.0}},
    "exit2": {"mcmcda": {"exit_depth": 2.0}},
    "exit3": {"mcmcda": {"exit_depth": 3.0}},
    "exit4": {"mcmcda": {"exit_depth": 4.0}},
    "pd0.8": {"mcmcda": {"pd": 0.8}},
    "pd0.9": {"mcmcda": {"pd": 0.9}},
    "lf1e-4": {"mcmcda": {"false_alarm_rate": 1e-4}},
    "su1": {"fusion": {"shared_unreported": 1}},
    "su3": {"fusion": {"shared_unreported": 3}},
    "esg3": {"fusion": {"expected_split_gain": 3.0}},
    "esg5": {"fusion": {"expected_split_gain": 5.0}},
    "union": {"fusion": {"multiplicity": False, "expected_gain": 1.0, "expected_split_gain": 4.0, "shared_support": None}},
    "union-e0": {"fusion": {"multiplicity": False, "expected_gain": 0.0, "shared_support": None}},
    "mult": {"fusion": {"expected_gain": 1.0, "expected_split_gain": 4.0, "shared_support": None}},
    "mult-e0": {"fusion": {"expected_split_gain": 4.0, "shared_support": None}},
    "mult-e0.5": {"fusion": {"expected_gain": 0.5, "expected_split_gain": 3.0, "shared_support": None}},
    "mult-e-0.5": {"fusion": {"expected_gain": -0.5, "expected_split_gain": 3.0, "shared_support": None}},
    "mult-esg2.5": {"fusion": {"expected_split_gain": 2.5, "shared_support": None}},
    "mult-esg3": {"fusion": {"expected_split_gain": 3.0, "shared_support": None}},
    "chain2": {"fusion": {"shared_chain": 2, "shared_support": None}},
    "chain3": {"fusion": {"shared_chain": 3, "shared_support": None}},
    "chain4": {"fusion": {"shared_chain": 4, "shared_support": None}},
    "chain5": {"fusion": {"shared_chain": 5, "shared_support": None}},
    "nosupport": {"fusion": {"shared_support": None}},
    "support-1": {"fusion": {"shared_support": -1.0}},
    "support-2": {"fusion": {"shared_support": -2.0}},
    "support-3": {"fusion": {"shared_support": -3.0}},
    "support-4": {"fusion": {"shared_support": -4.0}},
    "support-5": {"fusion": {"shared_support": -5.0}},
    "support-6": {"fusion": {"shared_support": -6.0}},
    "support-8": {"fusion": {"shared_support": -8.0}},
    "nosplit-expected": {"fusion": {"min_gain": 3.0, "expected_split_gain": float("inf")}},
    "shared-before": {"fusion": {"min_gain": 3.0, "shared_speed": 0.5, "shared_age": 6, "shared_edge": 1.0}},
    "issue21-before": {"fusion": {"min_gain": 3.0, "expected_split_gain": float("inf"), "shared_speed": 0.5, "shared_age": 6,
                                  "shared_edge": 1.0}},
}


def tracker_for(deployment, variant: str, seed: int):
    from bintrack.trackers.multi.fusion_config import FusionConfig
    from bintrack.trackers.multi.mcmcda_config import MCMCDAConfig
    from bintrack.trackers.multi.tracker import MCMCDATracker

    options = VARIANTS[variant]
    fusion = FusionConfig(**options.get("fusion", {}))
    config = MCMCDAConfig(**{**options.get("mcmcda", {}), "seed": seed})
    return MCMCDATracker(deployment, fusion, config)


def run_ours(args) -> tuple:
    """One grid: ours with each sampler seed (scores, fusion + MCMCDA ms/scan), and the grid's
    Case with the reports of the fusion without track aid (Stone Soup's input)."""
    name, path, seeds, variant = args
    from bintrack.formats import open_dataset
    from bintrack.bus_payloads import PositionReports, TrackSet
    from bintrack.pipeline import run_tracker

    case = vs.load_case(name, path)
    data = open_dataset(path)
    scores = []
    for seed in seeds:
        tracker = tracker_for(data.deployment, variant, seed)
        tracks, reports = {}, []
        start = time.perf_counter()
        for out in run_tracker(data, tracker):
            if isinstance(out, PositionReports):
                reports.append(out)
            elif isinstance(out, TrackSet):
                tracks[out.t] = [(k.track, k.x, k.y) for k in out.tracks]
        whole = time.perf_counter() - start
        case.reports = reports
        case.config = tracker.mcmcda.config
        scores.append(vs.score(tracks, case, [whole / max(len(reports), 1)]))
    if variant == "default":
        case.plain_reports = vs.plain_reports(data, PEER_BARS, PEER_MULTIPLICITY)
    return name, scores, case


SCORE_CACHE: Path | None = None  # scores of Stone Soup runs already made (set by main; None: none kept)
PEER_BARS: float | None = None  # the peers' fusion: bars in fixed nats (None), or scaled from this reference (--peer-bars)
PEER_MULTIPLICITY = False  # the peers' fusion counts each target detected on its own, as ours (--peer-multiplicity)
PEER_SOURCES = ("mcmcda_vs_stonesoup.py", "stonesoup_peers.py", "peer_gating.py", "peer_jipda.py", "peer_mfa.py",
                "peer_phd.py")


def run_stonesoup(args) -> tuple:
    """One Stone Soup tracker with one setting on one grid: (grid, kind, setting, Score or None
    if abandoned). Kept under ``SCORE_CACHE`` by what it depends on (the fused reports, the
    setting, the trackers' source), so that a run cut short resumes where it stopped."""
    name, case, kind, setting = args
    path = None if SCORE_CACHE is None else SCORE_CACHE / f"{_score_key(case, kind, setting)}.json"
    if path is not None and path.exists():
        kept = json.loads(path.read_text())
        return name, kind, setting, None if kept is None else vs.Score(**{**kept, "series": None})
    if kind in sp.PEERS:
        result = sp.run_peer(case, kind, setting, _field(case.path))
    else:
        result = vs.run_stonesoup(case, kind, setting, case.config)
    score = None if result is None else vs.score(result.tracks, case, result.step_s)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(None if score is None else score.__dict__ | {"series": None}, default=float))
    return name, kind, setting, score


def _score_key(case, kind: str, setting) -> str:
    digest = hashlib.sha256()
    for source in PEER_SOURCES:
        digest.update((Path(__file__).parent / source).read_bytes())
    digest.update(repr((kind, setting, case.path.name, _ConfigRepr(case.config), [r.t for r in case.reports])).encode())
    for reports in case.plain_reports:
        digest.update(repr((reports.t, [(r.x, r.y, r.cov) for r in reports.reports])).encode())
    return digest.hexdigest()[:32]


PEERS_IGNORE = ("exit_depth",)  # our publish policy's: no peer reads it


class _ConfigRepr:
    """The repr of our MCMCDAConfig without the fields no peer reads (``PEERS_IGNORE``), so that
    a change of those keeps the Stone Soup scores kept under ``--cache``."""

    def __init__(self, config):
        self.config = config

    def __repr__(self) -> str:
        c = self.config
        return f"{type(c).__qualname__}(" + ", ".join(f"{f.name}={getattr(c, f.name)!r}" for f in fields(c)
                                                     if f.repr and f.name not in PEERS_IGNORE) + ")"


# --------------------------------------------------------------------------- summaries


@dataclass
class Summary:
    gospa: float
    localisation: float
    missed: float
    false: float
    count_error: float
    switches: float      # summed over the half's grids
    ms_per_scan: float
    idf1: float = float("nan")
    track_ids: float = 0.0  # summed over the half's grids


def summarise(scores: list[vs.Score]) -> Summary:
    """Means over grids (switches and track ids summed)."""
    return Summary(*(float(np.mean([getattr(s, f) for s in scores]))
                     for f in ("gospa", "localisation", "missed", "false", "count_error")),
                   float(sum(s.switches for s in scores)), float(np.mean([s.ms_per_scan for s in scores])),
                   float(np.mean([s.idf1 for s in scores])), float(sum(s.track_ids for s in scores)))


def over_seeds(per_grid: list[list[vs.Score]]) -> tuple[Summary, list[Summary]]:
    """Ours over a half: the mean over sampler seeds of each figure, and each seed's summary."""
    per_seed = [summarise([grid[k] for grid in per_grid]) for k in range(len(per_grid[0]))]
    mean = Summary(*(float(np.mean([getattr(s, f) for s in per_seed])) for f in Summary.__dataclass_fields__))
    return mean, per_seed


def row(label: str, s: Summary, extra: str = "") -> str:
    return (f"{label:<26} {s.gospa:7.2f} {s.localisation:7.2f} {s.missed:7.2f} {s.false:7.2f} "
            f"{s.count_error:9.2f} {s.switches:8.1f} {s.idf1:6.3f} {s.track_ids:6.0f} {s.ms_per_scan:8.2f}  {extra}")


HEAD = (f"{'tracker':<26} {'GOSPA':>7} {'loc':>7} {'missed':>7} {'false':>7} {'|n err|':>9} "
        f"{'ID sw':>8} {'IDF1':>6} {'ids':>6} {'ms/scan':>8}")


# --------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="3 + 3 grids, 2 sampler seeds, 4 Stone Soup settings each")
    parser.add_argument("--grids", type=int, help="grids per half (default 8; --quick 3)")
    parser.add_argument("--mcmc-seeds", type=int, help="sampler seeds of ours (default 3; --quick 2)")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    parser.add_argument("--cache", type=Path, default=DEFAULT_CACHE, help=f"simulated grids (default {DEFAULT_CACHE})")
    parser.add_argument("--variant", action="append", default=[], choices=sorted(set(VARIANTS) - {"default"}),
                        help="also run this setting of ours on the tuning half (repeatable)")
    parser.add_argument("--json", type=Path, help="write the per-grid scores here")
    parser.add_argument("--plot", type=Path, default=DEFAULT_PLOT, help="PNG of GOSPA per grid (default docs/multi_target.png)")
    parser.add_argument("--stonesoup", action="append", choices=KINDS,
                        help=f"only this Stone Soup tracker (repeatable; default all: {', '.join(KINDS)})")
    parser.add_argument("--ours-only", action="store_true",
                        help="ours (defaults and --variant) on the tuning half only; no Stone Soup")
    parser.add_argument("--variants-only", action="store_true",
                        help="with --ours-only: the --variant runs alone, not the defaults beside them")
    parser.add_argument("--only", choices=sorted(VARIANTS),
                        help="just this setting of ours on both halves (no Stone Soup, no defaults)")
    parser.add_argument("--half", choices=("tuning", "held-out"),
                        help="with --only: that half alone (default both)")
    parser.add_argument("--tuned", type=Path,
                        help="the --json record of an earlier run: its chosen Stone Soup settings instead of tuning")
    parser.add_argument("--conditions", type=int, default=0, metavar="N",
                        help="also N grids per harder condition (benchmarks/multi_conditions.py; default none)")
    parser.add_argument("--conditions-only", action="store_true", help="only the conditions (needs --tuned)")
    parser.add_argument("--peer-bars", choices=("fixed", "scaled"), default="fixed",
                        help="the Stone Soup trackers' input: the fusion's reports with bars in fixed nats (default, "
                        "as they were tuned) or with ours, which grow with the sensors' evidence")
    parser.add_argument("--peer-multiplicity", action="store_true",
                        help="the Stone Soup trackers' input counts each target detected on its own, as ours does "
                        "(FusionConfig.multiplicity); default: over the union of the disks, as they were tuned")
    parser.add_argument("--fresh", action="store_true",
                        help="run every Stone Soup setting again (default: reuse the scores kept under --cache)")
    parser.add_argument("--conditions-plot", type=Path, default=DEFAULT_CONDITIONS_PLOT,
                        help="PNG of GOSPA per condition (default docs/multi_conditions.png)")
    args = parser.parse_args(argv)
    if importlib.util.find_spec("stonesoup") is None:
        print("multi_target: Stone Soup is not installed (pip install -e '.[bench]')", file=sys.stderr)
        return 2
    if args.conditions_only and not (args.tuned and args.conditions):
        print("multi_target: --conditions-only needs --tuned FILE and --conditions N", file=sys.stderr)
        return 2
    kinds = args.stonesoup or list(KINDS)
    if "MFA" in kinds and not args.ours_only and importlib.util.find_spec("ortools") is None:
        print("multi_target: the MFA peer needs ortools, which is not installed (pip install -e '.[bench]'; "
              "or leave it out: --stonesoup GNN --stonesoup JPDA …)", file=sys.stderr)
        return 2
    per_half = args.grids or (3 if args.quick else 8)
    if args.only and args.ours_only:
        parser.error("--only runs ours on both halves; --ours-only is the tuning half: give one of them")
    if args.half and not args.only:
        parser.error("--half goes with --only")
    seeds = list(range(args.mcmc_seeds or (2 if args.quick else 3)))
    args.cache.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    tuned = load_tuned(args.tuned) if args.tuned else {}
    missing = [k for k in kinds if args.tuned and k not in tuned]
    if missing:
        print(f"multi_target: {args.tuned} chose no setting for {', '.join(missing)}", file=sys.stderr)
        return 2

    halves = {} if args.conditions_only else suite(per_half)
    names = {}
    if halves:
        print(f"Suite (seed {SUITE_SEED}): {per_half} grids per half, 12 x 12 nodes at 5 m, range 8 m, period 0.5 s; "
              f"ours with sampler seeds {seeds[0]}..{seeds[-1]}.")
    for half, grids in halves.items():
        print(f"  {half}:")
        for spec in grids:
            name = f"{half[0]}{spec['seed']}"
            names[name] = (half, dataset(spec, args.cache))
            print(f"    {name}: {command(spec)}")
    print(flush=True)

    global SCORE_CACHE, PEER_BARS, PEER_MULTIPLICITY
    SCORE_CACHE = None if args.fresh else args.cache / "scores"
    from bintrack.trackers.multi.fusion_config import FusionConfig
    PEER_BARS = FusionConfig().evidence_reference if args.peer_bars == "scaled" else None
    PEER_MULTIPLICITY = args.peer_multiplicity
    ctx = multiprocessing.get_context("fork")  # the workers see SCORE_CACHE, PEER_BARS and PEER_MULTIPLICITY
    with ctx.Pool(args.jobs) as pool:
        def progress(label, jobs, fn):
            out = []
            for k, result in enumerate(pool.imap_unordered(fn, jobs), 1):
                out.append(result)
                say(f"  [{time.perf_counter() - started:6.0f} s] {label}: {k}/{len(jobs)}")
            return out

        if args.conditions_only:
            return run_conditions(progress, tuned, kinds, seeds, args)
        jobs = [(name, path, seeds, args.only or "default") for name, (half, path) in names.items()
                if (not args.ours_only or (half == "tuning" and not args.variants_only))
                and half == (args.half or half)]
        jobs += [(name, path, seeds, v) for v in args.variant for name, (half, path) in names.items() if half == "tuning"]
        ours: dict[tuple[str, str], list] = {}
        cases = {}
        # imap_unordered loses the job's order: carry (grid, variant) through
        tagged = [((name, variant), path, s, variant) for name, path, s, variant in jobs]
        for (key, scores, case) in progress("ours", tagged, _run_tagged):
            ours[key] = scores
            if key[1] == "default":
                cases[key[0]] = case

        tuning = [n for n, (h, _) in names.items() if h == "tuning"]
        held = [n for n, (h, _) in names.items() if h == "held-out"]
        if args.ours_only:
            print(_ours_table(ours, tuning, [*([] if args.variants_only else ["default"]), *args.variant], halves))
            return 0
        if args.only:
            for group in (tuning, held):
                if all((n, args.only) in ours for n in group):
                    print(_ours_table(ours, group, [args.only], halves))
            if args.json:  # for benchmarks/multi_chains.py
                args.json.write_text(json.dumps({"ours": {f"{n}/{v}": [s.__dict__ | {"series": None} for s in sc]
                                                          for (n, v), sc in ours.items()}}, default=float, indent=1))
            return 0
        stone: dict[tuple, vs.Score | None] = {}
        best: dict = {}
        for kind in kinds:
            if kind in tuned:  # chosen by an earlier run: scored on both halves
                best[kind] = tuned[kind]
                stage = [(n, cases[n], kind, best[kind]) for n in tuning + held]
                for n, k, s, sc in progress(f"Stone Soup {kind} as --tuned chose it", stage, run_stonesoup):
                    stone[(n, k, s)] = sc
                continue
            chosen = tune(progress, stone, cases, kind, tuning, args.quick)
            if chosen is None:
                print(f"multi_target: every Stone Soup {kind} setting ran over its time budget", file=sys.stderr)
                return 1
            best[kind] = chosen
            stage = [(n, cases[n], kind, best[kind]) for n in held]
            for n, k, s, sc in progress(f"Stone Soup {kind} on the held-out half", stage, run_stonesoup):
                stone[(n, k, s)] = sc

        print(report(ours, stone, best, kinds, tuning, held, halves, args.variant), flush=True)
        record = {
            "people": {n: _people(n, halves) for n in names},
            "best": {k: s.text(k) for k, s in best.items()},
            "best_fields": {k: {"type": type(s).__name__, **asdict(s)} for k, s in best.items()},
            "ours": {f"{n}/{v}": [s.__dict__ | {"series": None} for s in sc] for (n, v), sc in ours.items()},
            "stonesoup": {f"{n}/{k}/{s.text(k)}": (None if sc is None else sc.__dict__ | {"series": None})
                          for (n, k, s), sc in stone.items()}}
        if args.json:
            args.json.write_text(json.dumps(record, default=float, indent=1))
        plot(json.loads(json.dumps(record, default=float)), args.plot)
        print(f"plot: {args.plot}")
        if args.conditions:
            run_conditions(progress, best, kinds, seeds, args)
    print(f"(total {time.perf_counter() - started:.0f} s)")
    return 0


def tune(progress, stone: dict, cases: dict, kind: str, tuning: list[str], quick: bool):
    """Stone Soup ``kind``'s setting of lowest mean GOSPA over the tuning half: the first grid
    (``first_settings``), then ``stages`` one field at a time from the best so far (coordinate
    search); None if every setting ran over its time budget. Scores go into ``stone``."""
    settings = QUICK_SETTINGS[kind] if quick else first_settings(kind)
    stage = [(n, cases[n], kind, s) for s in settings for n in tuning]
    for n, k, s, sc in progress(f"Stone Soup {kind} on the tuning half", stage, run_stonesoup):
        stone[(n, k, s)] = sc
    ranked = _rank(stone, kind, settings, tuning)
    if not quick and ranked:
        for label, field, values in stages(kind):
            others = [replace(ranked[0][1], **{field: v}) for v in values]
            stage = [(n, cases[n], kind, s) for s in others for n in tuning]
            for n, k, s, sc in progress(f"Stone Soup {kind}, {label}", stage, run_stonesoup):
                stone[(n, k, s)] = sc
            settings = settings + others
            ranked = _rank(stone, kind, settings, tuning)
    return ranked[0][1] if ranked else None


def load_tuned(path: Path) -> dict:
    """kind -> setting from the ``best_fields`` of a ``--json`` record."""
    classes = {"Setting": vs.Setting, "PeerSetting": sp.PeerSetting}
    fields = json.loads(path.read_text()).get("best_fields", {})
    return {kind: classes[f.pop("type")](**f) for kind, f in fields.items()}


def report(ours: dict, stone: dict, best: dict, kinds: list[str], tuning: list[str], held: list[str], halves: dict,
           variants: list[str]) -> str:
    """Both halves' tables, the chosen settings, the spreads and the issue's acceptance lines."""
    out = []
    for half, group in (("tuning", tuning), ("held-out", held)):
        out.append(f"{half} half ({len(group)} grids, {sum(_people(n, halves) for n in group)} people): "
                   f"GOSPA c = 10 m, p = 2, alpha = 2 (m; parts in m²); |n err| mean |tracks - people|; ID switches "
                   f"and track ids summed; IDF1 (hit {vs.IDF1_HIT:g} m) mean; ms/scan: ours fusion + MCMCDA, Stone Soup "
                   f"its tracking step")
        out.append(HEAD)
        out.append("-" * len(HEAD))
        mean, per_seed = over_seeds([ours[(n, "default")] for n in group])
        g = [s.gospa for s in per_seed]
        out.append(row("ours (defaults)", mean, f"seeds: GOSPA {min(g):.2f}-{max(g):.2f}, switches "
                                                f"{min(s.switches for s in per_seed):.0f}-{max(s.switches for s in per_seed):.0f}"))
        if half == "tuning":
            for v in variants:
                vm, vseeds = over_seeds([ours[(n, v)] for n in group])
                vg = [s.gospa for s in vseeds]
                out.append(row(f"ours ({v})", vm, f"seeds: GOSPA {min(vg):.2f}-{max(vg):.2f}"))
        for kind in kinds:
            scores = [stone.get((n, kind, best[kind])) for n in group]
            if any(s is None for s in scores):
                out.append(f"{kind}: abandoned on some grid (over {vs.SETTING_BUDGET:g} s)")
                continue
            g = [s.gospa for s in scores]
            out.append(row(f"{kind} (tuned)", summarise(scores), f"grids: GOSPA sd {np.std(g):.2f}"))
        out.append("")
    for kind in kinds:
        out.append(f"Stone Soup {kind} chosen on the tuning half: {best[kind].text(kind)}")
    _, tune_seeds = over_seeds([ours[(n, "default")] for n in tuning])
    _, held_seeds = over_seeds([ours[(n, "default")] for n in held])
    spread = lambda xs: f"{np.mean(xs):.2f} (min {min(xs):.2f}, max {max(xs):.2f}, range {max(xs) - min(xs):.2f})"  # noqa: E731
    out.append(f"Spread of mean GOSPA: ours over sampler seeds, tuning half {spread([s.gospa for s in tune_seeds])}, "
               f"held-out half {spread([s.gospa for s in held_seeds])}")
    for kind in kinds:
        ranked = [m for m, _ in _rank(stone, kind, sorted({s for (_, k, s) in stone if k == kind}, key=str), tuning)]
        if len(ranked) > 1:
            out.append(f"  {kind} over its {len(ranked)} settings on the tuning half {spread(ranked)}; "
                       f"its best 3: {spread(ranked[:3])}")
    per_grid = [np.ptp([s.gospa for s in ours[(n, 'default')]]) for n in held]
    out.append(f"Per held-out grid, range of ours over sampler seeds: mean {np.mean(per_grid):.2f} m, max {max(per_grid):.2f} m")
    mean, _ = over_seeds([ours[(n, "default")] for n in held])
    peers = {k: summarise([stone[(n, k, best[k])] for n in held]) for k in kinds
             if all(stone.get((n, k, best[k])) for n in held)}
    if peers:
        top = min(peers, key=lambda k: peers[k].gospa)
        fewest = min(peers, key=lambda k: peers[k].count_error)
        steady = min(peers, key=lambda k: peers[k].switches)
        out.append("")
        out.append(f"Acceptance (issue 42) on the held-out half, against the best of the {len(peers)} tuned peers:")
        out.append(f"  mean GOSPA {mean.gospa:.2f} <= 0.85 x {top} {peers[top].gospa:.2f} = {0.85 * peers[top].gospa:.2f}: "
                   f"{'yes' if mean.gospa <= 0.85 * peers[top].gospa else 'no'} (ratio {mean.gospa / peers[top].gospa:.3f})")
        out.append(f"  mean count error {mean.count_error:.2f} <= {fewest} {peers[fewest].count_error:.2f}: "
                   f"{'yes' if mean.count_error <= peers[fewest].count_error else 'no'}")
        out.append(f"  identity switches {mean.switches:.1f} (mean over seeds) <= {steady} {peers[steady].switches:.0f}: "
                   f"{'yes' if mean.switches <= peers[steady].switches else 'no'}")
    return "\n".join(out)


def run_conditions(progress, best: dict, kinds: list[str], seeds: list[int], args) -> int:
    """The harder conditions (``multi_conditions``): ours and each peer with its chosen setting."""
    rows = conditions.grids(args.conditions)
    print(f"Conditions: {args.conditions} grids per row (seeds {conditions.SEED}..{conditions.SEED + args.conditions - 1}); "
          f"base: {command(dict(seed=conditions.SEED, **conditions.BASE))}; Stone Soup as chosen on the suite's tuning half:")
    for kind in kinds:
        print(f"  {kind}: {best[kind].text(kind)}")
    print(flush=True)
    names = {}
    for row_name, specs in rows.items():
        for spec in specs:
            names[f"{row_name}/{spec['seed']}"] = dataset(spec, args.cache)
    cases, ours = {}, {}
    for (key, scores, case) in progress("conditions: ours", [((n, "default"), p, seeds, "default") for n, p in names.items()],
                                        _run_tagged):
        ours[key[0]], cases[key[0]] = scores, case
    stone = {}
    stage = [(n, cases[n], kind, best[kind]) for kind in kinds for n in names]
    for n, k, _, sc in progress("conditions: Stone Soup", stage, run_stonesoup):
        stone[(n, k)] = sc
    gospa, counts, switches = {}, {}, {}
    for row_name in rows:
        grids = [n for n in names if n.split("/")[0] == row_name]
        for figure, into in (("gospa", gospa), ("count_error", counts), ("switches", switches)):
            into[row_name] = {"ours": [float(np.mean([getattr(s, figure) for s in ours[n]])) for n in grids]}
            for kind in kinds:
                got = [stone.get((n, kind)) for n in grids]
                into[row_name][kind] = None if any(s is None for s in got) else [getattr(s, figure) for s in got]
    text, lost = conditions.table(gospa, counts, switches, kinds)
    print("Conditions: mean GOSPA (m) ± sd over the row's grids (ours: each grid's mean over sampler seeds); "
          "ours/best: ours over the best peer's; n err and ID sw: ours/best peer's (switches summed)")
    print(text)
    print("Rows where a tuned peer beats us by more than 5 %: " + ("; ".join(lost) if lost else "none"), flush=True)
    conditions.plot(gospa, kinds, args.conditions_plot)
    print(f"plot: {args.conditions_plot}")
    if args.json:
        path = args.json.with_name(args.json.stem + "-conditions.json")
        path.write_text(json.dumps({"gospa": gospa, "count_error": counts, "switches": switches,
                                    "ours": {n: [s.__dict__ | {"series": None} for s in sc] for n, sc in ours.items()},
                                    "stonesoup": {f"{n}/{k}": (None if sc is None else sc.__dict__ | {"series": None})
                                                  for (n, k), sc in stone.items()}}, default=float, indent=1))
    return 0


def plot(data: dict, path: Path, extra: dict | None = None) -> None:
    """Mean GOSPA per grid: ours (mean over sampler seeds, bar from the lowest to the highest
    seed) beside each tuned Stone Soup tracker, tuning half then held-out half. ``data`` is the
    ``--json`` record; ``extra`` maps a label to another such record's ``ours`` for one
    more setting of ours."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    grids = sorted({k.split("/")[0] for k in data["ours"]}, key=lambda n: (n[0] != "t", n))
    fig, ax = plt.subplots(figsize=(10, 4.8))
    x = np.arange(len(grids))
    series = [("ours (defaults)", data["ours"], "default", -0.12, "C0")]
    for k, (label, ours) in enumerate((extra or {}).items()):
        variant = next(iter(ours)).split("/")[1]
        series.append((label, ours, variant, 0.12 + 0.08 * k, "C3"))
    for label, ours, variant, dx, colour in series:
        g = [[s["gospa"] for s in ours.get(f"{n}/{variant}", [])] for n in grids]
        mean = np.array([np.mean(v) if v else np.nan for v in g])
        lo = np.array([min(v) if v else np.nan for v in g])
        hi = np.array([max(v) if v else np.nan for v in g])
        # (a grid whose seeds agree can give a mean a rounding error outside min-max)
        ax.errorbar(x + dx, mean, yerr=np.maximum([mean - lo, hi - mean], 0.0), fmt="o", color=colour, capsize=3,
                    label=f"{label}: mean over sampler seeds, bar min-max")
    for kind, marker, colour in (("GNN", "s", "C1"), ("JPDA", "^", "C2"), ("JIPDA", "v", "C4"), ("MFA", "D", "C5"),
                                 ("PHD", "x", "C6")):
        by_grid = {}
        for key, sc in data["stonesoup"].items():
            n, k, _ = key.split("/", 2)
            if k == kind and sc is not None:
                by_grid.setdefault(n, []).append(sc["gospa"])
        best = data.get("best", {}).get(kind)
        if best is None:
            continue
        chosen = [data["stonesoup"].get(f"{n}/{kind}/{best}") for n in grids]
        ax.plot(x, [c["gospa"] if c else np.nan for c in chosen], marker, color=colour, ms=7,
                label=f"{kind}, setting tuned on the tuning half")
        if kind == "GNN":
            ax.vlines(x + 0.04, [min(by_grid.get(n, [np.nan])) for n in grids],
                      [max(by_grid.get(n, [np.nan])) for n in grids], color=colour, alpha=0.35, lw=4)
    split = sum(n[0] == "t" for n in grids) - 0.5
    ax.axvline(split, color="k", lw=1)
    ax.set_ylim(ax.get_ylim()[0], ax.get_ylim()[1] * 1.12)
    ax.text(split - 0.1, ax.get_ylim()[1] * 0.8, "tuning half", ha="right", va="top")
    ax.text(split + 0.1, ax.get_ylim()[1] * 0.8, "held-out half", ha="left", va="top")
    ax.set_xticks(x, [f"{n}\n{data['people'][n]} p" for n in grids], fontsize=8)
    ax.set_ylabel("mean GOSPA (c = 10 m, p = 2), m")
    ax.set_title("Multi-target suite: GOSPA per grid (shaded: GNN over the settings tried on the tuning half)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize="x-small", loc="upper left", ncol=2)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def first_settings(kind: str) -> list:
    """The first grid of settings a Stone Soup tracker is tuned over."""
    if kind in sp.PEERS:
        return list(sp.FIRST[kind])
    return [vs.Setting(vs.GATES[kind][0], m, d) for m, d in itertools.product(MIN_POINTS, DELETERS)]


def stages(kind: str) -> list[tuple[str, str, tuple]]:
    """(label, field, values) tried one field at a time from the best setting so far."""
    if kind in sp.PEERS:
        return sp.STAGES[kind]
    out = [("other gate", "gate", vs.GATES[kind][1:])]
    if kind == "JPDA":
        out.append(("detection probability", "pd", JPDA_PD))
    return out + [("other process noise", "process_noise", PEER_PROCESS_NOISE)]


def _field(path: Path) -> tuple:
    """(xmin, ymin, xmax, ymax) of the dataset's region, m."""
    from bintrack.formats import open_dataset

    r = open_dataset(path).deployment.region
    return r.xmin, r.ymin, r.xmax, r.ymax


def _ours_table(ours: dict, group: list[str], variants: list[str], halves: dict) -> str:
    """Ours with each variant on ``group``: the summary and the per-grid GOSPA (mean over seeds)."""
    half = "tuning" if group[0].startswith("t") else "held-out"
    lines = [f"{half} half ({len(group)} grids, {sum(_people(n, halves) for n in group)} people), ours only", HEAD,
             "-" * len(HEAD)]
    for v in variants:
        mean, per_seed = over_seeds([ours[(n, v)] for n in group])
        g = [s.gospa for s in per_seed]
        grids = " ".join(f"{np.mean([s.gospa for s in ours[(n, v)]]):.2f}" for n in group)
        lines.append(row(f"ours ({v})", mean, f"seeds {min(g):.2f}-{max(g):.2f}; per grid {grids}"))
    return "\n".join(lines)


def _run_tagged(args):
    key, path, seeds, variant = args
    _, scores, case = run_ours((key[0], path, seeds, variant))
    return key, scores, case


def _people(name: str, halves: dict) -> int:
    for grids in halves.values():
        for spec in grids:
            if name[1:] == str(spec["seed"]):
                return spec["people"]
    return 0


def _rank(stone: dict, kind: str, settings, grids) -> list[tuple[float, vs.Setting]]:
    """Settings run on every grid of ``grids``, by mean GOSPA over them (lowest first)."""
    ranked = []
    for s in settings:
        scores = [stone.get((n, kind, s)) for n in grids]
        if all(sc is not None for sc in scores):
            ranked.append((float(np.mean([sc.gospa for sc in scores])), s))
    return sorted(ranked, key=lambda r: r[0])


if __name__ == "__main__":
    sys.exit(main())
