"""CLEAR MOT (Bernardin and Stiefelhagen, "Evaluating multiple object tracking performance: the
CLEAR MOT metrics", EURASIP JIVP 2008) and the identity scores IDF1/IDP/IDR (Ristani et al.,
ECCV 2016 workshops), for multi-target tracks on the floor.

Per frame, a target keeps the track it was matched to in the previous frame while that track is
still within the hit threshold; the other targets and tracks are then paired either greedily
(``"greedy"``: repeatedly the closest remaining pair within the threshold — how Milan et al.
score the real ceiling-PIR recordings in *Privacy Preserving Multi-target Tracking*, ACCV 2014
workshops) or by an optimal assignment (``"hungarian"``, the original CLEAR MOT). Unpaired
targets are misses (FN), unpaired tracks false positives (FP); a mismatch (identity switch) is a
target present in the previous frame that is matched to another track than the one it was last
matched to. MOTA = 1 − (FN + FP + IDSW)/ΣGT; MOTP as a distance is the mean distance of the
matched pairs, and as Milan et al.'s percentage 1 − that mean / threshold.

IDF1 comes from motmetrics (a global one-to-one assignment of track ids to target ids over the
whole sequence), fed with the same frames and the same threshold.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

MATCHINGS = ("greedy", "hungarian")


@dataclass(frozen=True)
class Frame:
    """One scored frame: time ``t`` (s), target ids and positions (n, 2), track ids and positions
    (m, 2), in the dataset's units."""

    t: float
    targets: tuple[str, ...]
    target_xy: np.ndarray
    tracks: tuple[int, ...]
    track_xy: np.ndarray


@dataclass(frozen=True)
class ClearMot:
    """The CLEAR MOT counts and scores of a sequence (``threshold`` in units)."""

    threshold: float
    matching: str
    frames: int
    ground_truth: int
    matches: int
    false_positives: int
    misses: int
    switches: int
    distance_sum: float
    count_error_mean: float | None
    idf1: float | None
    idp: float | None
    idr: float | None

    @property
    def mota(self) -> float | None:
        """1 − (FN + FP + IDSW)/ΣGT (a fraction; None without ground truth)."""
        if not self.ground_truth:
            return None
        return 1.0 - (self.misses + self.false_positives + self.switches) / self.ground_truth

    @property
    def motp_distance(self) -> float | None:
        """Mean distance of the matched pairs, units."""
        return self.distance_sum / self.matches if self.matches else None

    @property
    def motp(self) -> float | None:
        """1 − mean matched distance / threshold (Milan et al.'s MOTP, a fraction)."""
        d = self.motp_distance
        return None if d is None else 1.0 - d / self.threshold

    @property
    def recall(self) -> float | None:
        return self.matches / self.ground_truth if self.ground_truth else None

    @property
    def precision(self) -> float | None:
        n = self.matches + self.false_positives
        return self.matches / n if n else None


def _distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.hypot(*(a[:, None, :] - b[None, :, :]).transpose(2, 0, 1)) if len(a) and len(b) else np.zeros((len(a), len(b)))


def _pair(d: np.ndarray, rows: list[int], cols: list[int], threshold: float, matching: str) -> list[tuple[int, int]]:
    """Pairs (row, col) among ``rows`` × ``cols`` of ``d`` within ``threshold``."""
    if not rows or not cols:
        return []
    sub = d[np.ix_(rows, cols)]
    out = []
    if matching == "hungarian":
        a, b = linear_sum_assignment(np.where(sub <= threshold, sub, 1e9))
        return [(rows[i], cols[j]) for i, j in zip(a, b) if sub[i, j] <= threshold]
    sub = sub.copy()
    while sub.size:
        k = int(np.argmin(sub))  # first minimum in row-major order: ties go to the lower indices
        i, j = divmod(k, sub.shape[1])
        if not sub[i, j] <= threshold:
            break
        out.append((rows[i], cols[j]))
        sub[i, :] = np.inf
        sub[:, j] = np.inf
    return out


def clear_mot(frames: Sequence[Frame], threshold: float, matching: str = "greedy") -> ClearMot:
    """CLEAR MOT over ``frames`` (in time order) with hit threshold ``threshold`` (units): a
    target and a track at most that far apart may match. ``matching``: "greedy" or "hungarian"."""
    if matching not in MATCHINGS:
        raise ValueError(f"unknown matching {matching!r} (expected {' or '.join(MATCHINGS)})")
    if not threshold > 0:
        raise ValueError(f"hit threshold must be positive, got {threshold}")
    previous: dict[str, int] = {}      # target -> track matched in the previous frame
    last: dict[str, int] = {}          # target -> track it was last matched to
    present_before: set[str] = set()
    gt = matches = fp = fn = switches = 0
    dist = 0.0
    count_errors = []
    for frame in frames:
        d = _distances(frame.target_xy, frame.track_xy)
        col_of = {tr: j for j, tr in enumerate(frame.tracks)}
        pairs: dict[int, int] = {}  # target row -> track col
        for i, target in enumerate(frame.targets):
            j = col_of.get(previous.get(target, -1))
            if j is not None and j not in pairs.values() and d[i, j] <= threshold:
                pairs[i] = j
        rows = [i for i in range(len(frame.targets)) if i not in pairs]
        cols = [j for j in range(len(frame.tracks)) if j not in pairs.values()]
        pairs.update(_pair(d, rows, cols, threshold, matching))
        for i, j in pairs.items():
            target, track = frame.targets[i], frame.tracks[j]
            if target in present_before and target in last and last[target] != track:
                switches += 1
            last[target] = track
            dist += float(d[i, j])
        previous = {frame.targets[i]: frame.tracks[j] for i, j in pairs.items()}
        present_before = set(frame.targets)
        gt += len(frame.targets)
        matches += len(pairs)
        fp += len(frame.tracks) - len(pairs)
        fn += len(frame.targets) - len(pairs)
        count_errors.append(abs(len(frame.tracks) - len(frame.targets)))
    idf1, idp, idr = _identity_scores(frames, threshold)
    return ClearMot(threshold, matching, len(frames), gt, matches, fp, fn, switches, dist,
                    float(np.mean(count_errors)) if count_errors else None, idf1, idp, idr)


def _identity_scores(frames: Sequence[Frame], threshold: float) -> tuple[float | None, float | None, float | None]:
    """IDF1, IDP, IDR from motmetrics over ``frames`` (pairs farther than ``threshold`` cannot match)."""
    import motmetrics

    acc = motmetrics.MOTAccumulator(auto_id=True)
    number: dict[str, int] = {}  # motmetrics wants ids of one type: targets numbered in order of appearance
    for frame in frames:
        d = _distances(frame.target_xy, frame.track_xy)
        targets = [number.setdefault(k, len(number)) for k in frame.targets]
        acc.update(targets, [int(t) for t in frame.tracks], np.where(d <= threshold, d, np.nan))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        summary = motmetrics.metrics.create().compute(acc, metrics=["idf1", "idp", "idr"], name="all")
    values = [float(summary[k].iloc[0]) for k in ("idf1", "idp", "idr")]
    return tuple(None if not np.isfinite(v) else v for v in values)
