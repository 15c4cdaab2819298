"""Where the real tracker's missed people come from (issue: real sensors): each annotated person
whom no track follows, by what the scan held near them.

    .venv/bin/python benchmarks/real_pir_misses.py [--data ../shared/realdata/irtracking] [--sequence r1-easy] [--seeds N]

The chain a user runs on one public sequence (``bintrack import``, ``bintrack calibrate`` of a
copy without truth.csv), then ``mcmcda`` with seeds 0..N−1 run in this process, so that the
fusion's reports of each scan are seen beside its tracks. Each annotated person-sample inside
[0, 8] × [0, 14] m is matched one to one to the tracks of its scan within 1.5 m (optimal
assignment), as CLEAR MOT counts a hit; a person left unmatched is put in the first class that
fits:

* **beside someone**: a track lies within 1.5 m, but it is matched to another person (two people
  on one blob), by the distance to the nearest other person; and how many of them a track
  followed at most 5 samples (2.5 s) before;
* **a report, no track**: the fusion placed a report within 1.5 m, but no track was shown there;
* **no report**: by how many sensors within 1.5 m fired in the sample (the fusion places a new
  person on two detections, a track's person on one).

The default sequence is r1-easy, the one the real-PIR settings were chosen on.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

sys.path.insert(0, str(Path(__file__).resolve().parent))
from real_sensors import SEQUENCES, stated_and_calibrated  # noqa: E402

from bintrack.bus_payloads import PositionReports, TrackSet  # noqa: E402
from bintrack.calibration.sample_series import SampleSeries, sample_series  # noqa: E402
from bintrack.formats import Dataset, open_dataset  # noqa: E402
from bintrack.pipeline import run_tracker  # noqa: E402
from bintrack.trackers import TrackerOptions, make_tracker  # noqa: E402

HIT = 1.5  # m: CLEAR MOT's hit threshold, as the authors score it
AREA = (0.0, 0.0, 8.0, 14.0)  # m: the tracking area the authors score in
LOST_SINCE = 5  # samples (2.5 s): a person beside someone whose own track was lost this recently
LOST = f"  of them followed {LOST_SINCE} samples before or less"


def annotated(data: Dataset) -> dict[float, list[tuple[str, float, float]]]:
    """Per sample time (s): the annotated people inside ``AREA``, (id, x, y) in m."""
    people: dict[float, list] = {}
    for row in data.truth():
        if AREA[0] <= row.x <= AREA[2] and AREA[1] <= row.y <= AREA[3]:
            people.setdefault(round(row.t, 3), []).append((row.target, row.x, row.y))
    return people


def classes(data: Dataset, series: SampleSeries, people: dict, seed: int) -> Counter:
    """The classes of one run's person-samples (module text); 'followed' for the matched ones.
    ``series``: the sensors' samples; ``people``: :func:`annotated`."""
    reports, tracks = {}, {}
    for out in run_tracker(data, make_tracker("mcmcda", data.deployment, TrackerOptions(seed=seed))):
        if isinstance(out, PositionReports):
            reports[round(out.t, 3)] = np.array([(r.x, r.y) for r in out.reports]).reshape(-1, 2)
        elif isinstance(out, TrackSet):
            tracks[round(out.t, 3)] = np.array([(tr.x, tr.y) for tr in out.tracks]).reshape(-1, 2)
    out = Counter()
    last_followed: dict[str, int] = {}  # person → the sample they were last followed in
    for k_t, t in enumerate(sorted(people)):
        names = [p[0] for p in people[t]]
        here = np.array([p[1:] for p in people[t]])
        shown = tracks.get(t, np.zeros((0, 2)))
        dist = np.linalg.norm(here[:, None, :] - shown[None, :, :], axis=2)
        rows, cols = linear_sum_assignment(np.where(dist <= HIT, dist, 1e6)) if len(shown) else ((), ())
        matched = {r for r, c in zip(rows, cols) if dist[r, c] <= HIT}
        k = int(round((t - series.t0) / series.period))
        fired = series.status[k] > 0 if 0 <= k < len(series.status) else np.zeros(len(series.ids), dtype=bool)
        near = reports.get(t, np.zeros((0, 2)))
        for i, person in enumerate(here):
            if i in matched:
                out["followed"] += 1
                last_followed[names[i]] = k_t
            elif len(shown) and dist[i].min() <= HIT:
                other = np.delete(here, i, axis=0)
                gap = np.linalg.norm(other - person, axis=1).min() if len(other) else np.inf
                out["beside someone ≤ 1 m" if gap <= 1 else "beside someone 1-2 m" if gap <= 2
                    else "beside someone more than 2 m away"] += 1
                if k_t - last_followed.get(names[i], -LOST_SINCE - 1) <= LOST_SINCE:
                    out[LOST] += 1
            elif len(near) and np.linalg.norm(near - person, axis=1).min() <= HIT:
                out["a report, no track"] += 1
            else:
                n = int((fired & (np.linalg.norm(series.positions - person, axis=1) <= HIT)).sum())
                out[f"no report, {min(n, 2)}{'+' if n >= 2 else ''} fired within 1.5 m"] += 1
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[2] / "shared/realdata/irtracking")
    parser.add_argument("--sequence", choices=SEQUENCES, default="r1-easy")
    parser.add_argument("--seeds", type=int, default=5, help="mcmcda seeds 0..N-1 (default 5)")
    args = parser.parse_args()
    if not (args.data / "sensors.csv").exists():
        print(f"skipped: the real recording is not at {args.data}")
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        data = open_dataset(stated_and_calibrated(args.data, args.sequence, work))
        series, people = sample_series(data.deployment, data.events()), annotated(data)
        runs = []
        for seed in range(args.seeds):
            print(f"seed {seed} ...", file=sys.stderr, flush=True)
            runs.append(classes(data, series, people, seed))
    names = sorted({name for run in runs for name in run if name != LOST},
                   key=lambda n: (n != "followed", -sum(r[n] for r in runs)))
    total = sum(runs[0][name] for name in names)
    print(f"{args.sequence}: {total} annotated person-samples in the area; per run, mean (range) over seeds 0-{args.seeds - 1}")

    def line(name: str, counts: list[int]) -> None:
        print(f"  {name:<48} {np.mean(counts):7.1f} ({min(counts)}-{max(counts)})  {np.mean(counts) / total:6.1%}")

    for name in names:
        line(name, [run[name] for run in runs])
    line("beside someone, all", [sum(n for name, n in run.items() if name.startswith("beside")) for run in runs])
    line(LOST, [run[LOST] for run in runs])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
