"""The JIPDA peer of benchmarks/multi_target.py (benchmarks/peer_jipda.py, built from Stone Soup's
parts): a target's track gains existence while it is seen and loses it once it is not; a
one-off false detection's track loses it at once and is never reported."""

from __future__ import annotations

import datetime
from pathlib import Path

import numpy as np
import pytest

stonesoup = pytest.importorskip("stonesoup", reason="Stone Soup (the bench extra) is not installed")

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"
PERIOD = 0.5  # s
T0 = datetime.datetime(2000, 1, 1)


@pytest.fixture
def jipda(monkeypatch):
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    from stonesoup.models.transition.linear import CombinedLinearGaussianTransitionModel, ConstantVelocity
    from stonesoup.predictor.kalman import KalmanPredictor
    from stonesoup.updater.kalman import KalmanUpdater

    from peer_jipda import JIPDATracker

    model = CombinedLinearGaussianTransitionModel([ConstantVelocity(0.05), ConstantVelocity(0.05)])
    return JIPDATracker(KalmanPredictor(model), KalmanUpdater(measurement_model=None), pd=0.8,
                        clutter_density=1e-3, survival=0.98, birth=0.1, confirm=0.9, delete=0.05)


def detection(x: float, y: float, when):
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.types.detection import Detection

    model = LinearGaussian(ndim_state=4, mapping=(0, 2), noise_covar=np.eye(2))
    return Detection(np.array([[x], [y]]), timestamp=when, measurement_model=model)


def test_existence_rises_on_a_target_and_falls_on_a_false_track(jipda):
    rng = np.random.default_rng(7)
    history: list[dict] = []   # per scan: track -> existence after the scan
    reported: list[set] = []   # per scan: ids reported
    for k in range(40):
        when = T0 + datetime.timedelta(seconds=PERIOD * k)
        found = set()
        if k < 24 and (k < 3 or rng.random() < 0.8):  # walks at 1 m/s, seen 4 scans in 5, gone at scan 24
            found.add(detection(5.0 + PERIOD * k + rng.normal(0, 0.5), 10.0 + rng.normal(0, 0.5), when))
        if k == 5:
            found.add(detection(40.0, 40.0, when))  # once, far from anyone
        reported.append({key for key, _, _ in jipda.step(when, found)})
        history.append(dict(jipda.existence))

    target = next(iter(history[0]))
    false = next(t for t in history[5] if t is not target)
    assert np.hypot(false.states[0].state_vector[0, 0] - 40.0, false.states[0].state_vector[2, 0] - 40.0) < 1e-9

    seen = [history[k][target] for k in range(4)]
    assert seen[0] == pytest.approx(0.1) and all(b > a for a, b in zip(seen, seen[1:])), seen
    assert min(history[k][target] for k in range(3, 24)) > 0.9  # confirmed throughout the walk
    assert all(target.id in reported[k] for k in range(2, 24))
    gone = [history[k].get(target, 0.0) for k in range(23, 40)]
    assert all(b < a or b == 0.0 for a, b in zip(gone, gone[1:])), gone  # falls once nothing is seen
    assert target not in history[-1] and not reported[-1]

    assert history[5][false] == pytest.approx(0.1)
    assert all(false not in history[k] for k in range(6, 40))  # below 0.05 at the next scan: deleted
    assert not any(false.id in ids for ids in reported)
    assert all(len(ids) <= 1 for ids in reported)  # nothing else was ever confirmed


def test_one_track_follows_the_existence_update_of_the_paper(jipda):
    """One track, one scan (Mušicki and Evans 2004, eq. 30 with a single track): with no
    detection r = r⁻(1 − P_D P_G)/(1 − P_D P_G r⁻); with one detection of likelihood ratio
    L = P_D N(z; ẑ, S)/λ, r = r⁻(L + 1 − P_D P_G)/(1 − P_D P_G r⁻ + r⁻ L); r⁻ = p_s r."""
    from scipy.stats import multivariate_normal

    jipda.step(T0, {detection(5.0, 10.0, T0)})
    (track, r0), = jipda.existence.items()
    pd_pg, survival = 0.8 * 0.99, 0.98

    when = T0 + datetime.timedelta(seconds=PERIOD)
    z = detection(6.0, 11.0, when)
    prediction = jipda.hypothesiser.hypothesiser.predictor.predict(track, timestamp=when)
    mean = np.asarray(prediction.state_vector, dtype=float)[[0, 2], 0]
    s = np.asarray(prediction.covar, dtype=float)[np.ix_([0, 2], [0, 2])] + np.eye(2)
    ratio = 0.8 * multivariate_normal.pdf([6.0, 11.0], mean=mean, cov=s) / 1e-3
    jipda.step(when, {z})
    r_pred = survival * r0
    assert jipda.existence[track] == pytest.approx(r_pred * (ratio + 1 - pd_pg) / (1 - pd_pg * r_pred + r_pred * ratio))

    r1 = jipda.existence[track]
    jipda.step(when + datetime.timedelta(seconds=PERIOD), set())
    r_pred = survival * r1
    assert jipda.existence[track] == pytest.approx(r_pred * (1 - pd_pg) / (1 - pd_pg * r_pred))
