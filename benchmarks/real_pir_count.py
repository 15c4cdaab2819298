"""Could the number of people come from how many sensors fire? A count filter on r1-easy, the
selection sequence of the real ceiling-PIR recording (issue: real sensors).

    .venv/bin/python benchmarks/real_pir_count.py [--data ../shared/realdata/irtracking] [--switch 0.02]

The count error the tracker leaves is mostly people missed inside another's blob. The count of a
room changes slowly (people come in and leave through doors), while the number of firing sensors
k_t grows with it, about linearly. So a hidden Markov model over the count n (a person comes or
goes with probability ``--switch`` per sample, and k_t ~ Normal(a·n + b, b + a·n)) filtered online
gives a count from the detections alone, if the slope a (firing sensors per person) and the
false alarms b are known:

* **given the truth's slope**: a and b fitted by least squares of k_t on the true count (an
  oracle for the slope, not a tracker);
* **from the calibrated sensors**: a = the calibrated disks' expected firings of a person, Σ_i
  pd_i·[d_i < R_i], averaged over the annotated positions, and b = Σ_i pfa_i (the best the
  calibration can say; averaged over the room's floor it is lower still); the same averaged over
  the tracker's own tracks instead, which needs no truth;
* **blind**: a and b of the largest likelihood of k_t alone under the HMM (a grid).

The count error is very sensitive to a: 10 % off doubles it.

The filter is the tracker's own (:class:`bintrack.trackers.multi.firing_count.FiringCount`, which
the fusion of real PIR runs with a learned from the people it places). Printed beside the
tracker's count error (``bintrack eval``'s ``target_count_error_mean``, mcmcda seed 0). Never
r1-medium. About half a minute. What the tracker makes of it: docs/real_sensors.md, "The count
from how many sensors fire" and "The count's people sought by the fit".
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from real_sensors import EVAL, bintrack, stated_and_calibrated  # noqa: E402

from bintrack.calibration.sample_series import sample_series  # noqa: E402
from bintrack.deployment_model import DiskSensor  # noqa: E402
from bintrack.formats import Dataset, open_dataset, read_tracks  # noqa: E402
from bintrack.trackers.multi.firing_count import FiringCount  # noqa: E402

AREA = (0.0, 0.0, 8.0, 14.0)  # m: where people are counted, as the scores count them


def count_filter(k: np.ndarray, a: float, b: float, switch: float) -> tuple[np.ndarray, float]:
    """The most likely count per sample of the HMM above with a fixed slope ``a`` (the tracker's
    :class:`FiringCount` with no people placed), filtered online (forward only), and the log
    likelihood of ``k`` under it (nats)."""
    count, out, log_l = FiringCount(switch, floor=a, false_alarms=b), [], 0.0
    for fired in k:
        log_l += count.update(int(fired))
        out.append(int(np.argmax(count.belief)))
    return np.array(out), log_l


def firings_and_counts(data: Dataset) -> tuple[np.ndarray, np.ndarray, np.ndarray, list]:
    """k, the firing sensors in every sample; the annotated samples' indices; the true count in
    each of them, people inside ``AREA`` (as the scores count them); and those people's truth rows."""
    series = sample_series(data.deployment, data.events())
    k = series.status.sum(axis=1)
    xmin, ymin, xmax, ymax = AREA
    truth = [row for row in data.truth() if xmin <= row.x <= xmax and ymin <= row.y <= ymax]
    counts = Counter(int(round((row.t - series.t0) / series.period)) for row in truth)
    annotated = sorted({int(round((row.t - series.t0) / series.period)) for row in data.truth()})
    frames = np.array([j for j in annotated if 0 <= j < len(k)])
    return k, frames, np.array([counts.get(j, 0) for j in frames]), truth


def blind_fit(k: np.ndarray, switch: float) -> tuple[float, float]:
    """(a, b) of the largest likelihood of ``k`` alone, on a grid (a 0.8–2.6 by 0.05, b 0.05–0.8)."""
    grid = [(a, b) for a in np.arange(0.8, 2.6001, 0.05) for b in (0.05, 0.1, 0.2, 0.35, 0.5, 0.8)]
    return max(grid, key=lambda ab: count_filter(k, *ab, switch)[1])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[2] / "shared/realdata/irtracking")
    parser.add_argument("--switch", type=float, default=0.02, help="chance per sample that someone comes or goes")
    args = parser.parse_args()
    if not (args.data / "r1-easy.txt").exists():
        print(f"skipped: the real recording is not at {args.data}")
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        dataset = stated_and_calibrated(args.data, "r1-easy", work)
        data = open_dataset(dataset)
        k, frames, n, truth = firings_and_counts(data)
        sensors = [s for s in data.deployment.sensors if isinstance(s, DiskSensor)]
        where = np.array([(row.x, row.y) for row in truth])
        centres, reach = np.array([(s.x, s.y) for s in sensors]), np.array([s.range for s in sensors])
        gaps = np.hypot(where[:, None, 0] - centres[None, :, 0], where[:, None, 1] - centres[None, :, 1])
        calibrated = (float(((gaps < reach) * np.array([s.pd for s in sensors])).sum(axis=1).mean()),
                      float(sum(s.pfa for s in sensors)))
        supervised = tuple(float(v) for v in np.polyfit(n, k[frames], 1))
        tracks = work / "tracks.csv"
        bintrack("track", str(dataset), "--tracker", "mcmcda", "--seed", "0", "--out", str(tracks), "--no-progress")
        ours = json.loads(bintrack("eval", str(dataset), str(tracks), *EVAL, "--json").splitlines()[0])
        shown = np.array([(row.x, row.y) for row in read_tracks(tracks)])
        gaps = np.hypot(shown[:, None, 0] - centres[None, :, 0], shown[:, None, 1] - centres[None, :, 1])
        at_tracks = (float(((gaps < reach) * np.array([s.pd for s in sensors])).sum(axis=1).mean()), calibrated[1])
    print(f"r1-easy: {len(frames)} annotated samples, {n.mean():.2f} people on average; count error per frame "
          f"(|estimate − truth|, mean), HMM switch {args.switch} per sample")
    print(f"{'count from':<44} {'a':>6} {'b':>6} {'count error':>12}")
    for label, (a, b) in (("firing sensors, slope given by the truth", supervised),
                          ("firing sensors, slope from the calibration", calibrated),
                          ("the same at the tracks' positions (blind)", at_tracks),
                          ("firing sensors, slope fitted blind", blind_fit(k, args.switch))):
        estimate = count_filter(k, a, b, args.switch)[0][frames]
        print(f"{label:<44} {a:>6.2f} {b:>6.2f} {np.abs(estimate - n).mean():>12.3f}")
    print(f"{'the tracker (mcmcda seed 0, its tracks)':<44} {'':>6} {'':>6} {ours['target_count_error_mean']:>12.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
