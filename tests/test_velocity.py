import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bintrack.trackers.arc.velocity import LocalClock, VelocityEstimator


def feed(estimator, clock, points, arcs):
    out = None
    for (t, x, y), arc in zip(points, arcs):
        out = estimator.observe(clock.local(t), x, y, arc)
    return out


@given(st.floats(-1e4, 1e4), st.floats(-5, 5), st.floats(-5, 5))
@settings(max_examples=50, deadline=None)
def test_exact_on_a_constant_velocity_whatever_the_clock_offset(offset, vx, vy):
    points = [(t, 10 + vx * t, -3 + vy * t) for t in np.linspace(0, 30, 8)]
    v = feed(VelocityEstimator(), LocalClock(offset=offset), points, [0.1] * 8)
    assert v == pytest.approx((vx, vy), abs=1e-6)


def test_a_clock_skew_scales_the_speed_only():
    points = [(t, 2.0 * t, 1.0 * t) for t in np.linspace(0, 20, 6)]
    v = feed(VelocityEstimator(), LocalClock(offset=5.0, skew=0.01), points, [0.1] * 6)
    assert v == pytest.approx((2.0 / 1.01, 1.0 / 1.01))


def test_long_arcs_are_not_used():
    est = VelocityEstimator(max_arc=0.3)
    assert est.observe(0.0, 0.0, 0.0, 0.1) is None
    assert est.observe(1.0, 50.0, 50.0, 2.5) is None  # a long arc: a poor location, ignored
    assert est.observe(2.0, 4.0, 0.0, None) is None  # no arc known: ignored
    assert est.observe(4.0, 8.0, 0.0, 0.2) == pytest.approx((2.0, 0.0))


def test_follows_a_change_of_speed_after_span_estimates():
    est = VelocityEstimator(span=3)
    for t in range(5):
        est.observe(float(t), 1.0 * t, 0.0, 0.1)
    for t in range(5, 10):
        est.observe(float(t), 4.0 + 3.0 * (t - 4), 0.0, 0.1)
    assert est.velocity() == pytest.approx((3.0, 0.0))


def test_no_velocity_from_a_displacement_smaller_than_the_positions_uncertainty():
    est = VelocityEstimator(max_arc=0.5)
    assert est.observe(0.00, 0.0, 0.0, 0.2, radius=40.0) is None  # uncertainty 4 units each
    assert est.observe(0.05, 9.0, 0.0, 0.2, radius=40.0) is None  # 9 < 2·(4 + 4): mostly error
    assert est.observe(6.00, 17.0, 0.0, 0.2, radius=40.0) is not None


def test_bad_parameters_are_refused():
    with pytest.raises(ValueError):
        VelocityEstimator(max_arc=0)
    with pytest.raises(ValueError):
        VelocityEstimator(span=1)


def _arc_rows(**clock):
    from bintrack.formats import open_dataset, write_dataset
    from bintrack.pipeline import output_rows, run_tracker
    from bintrack.sim.scenarios import simulate
    from bintrack.trackers import make_tracker
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        result = simulate("uniform-800", seed=3, sensing_range=40.0, trajectory="linear", **clock)
        ds = open_dataset(write_dataset(Path(tmp) / "d", *result))
        return ds.truth(), list(output_rows(run_tracker(ds, make_tracker("arc", ds.deployment))))


def test_arc_tracker_velocity_in_the_paper_setting_and_without_clock_synchronisation():
    from bintrack.evaluation.metrics import truth_paths, velocity_errors

    truth, rows = _arc_rows()
    with_velocity = [r for r in rows if r.vx is not None]
    assert len(with_velocity) > 0.9 * len(rows)
    path = next(iter(truth_paths(truth).values()))
    errors = velocity_errors(with_velocity, path)
    assert np.nanmedian(errors) < 0.15  # speed R/15 = 2.67 units/s; paper §5.4: mean 0.076
    # per-node clock offsets of up to ±1000 s change nothing; skews of ±0.1 % scale slightly
    _, offset_rows = _arc_rows(clock_offset=1000.0)
    assert [r.vx is None for r in offset_rows] == [r.vx is None for r in rows]
    both = [(a, b) for a, b in zip(offset_rows, rows) if a.vx is not None]
    assert np.allclose([(a.vx, a.vy) for a, _ in both], [(b.vx, b.vy) for _, b in both], atol=1e-6)
    _, skewed_rows = _arc_rows(clock_skew=0.001)
    assert [(r.x, r.y) for r in skewed_rows] == [(r.x, r.y) for r in rows]
    assert np.nanmedian(velocity_errors([r for r in skewed_rows if r.vx is not None], path)) < 0.15
