"""The arc algebra of bintrack.trackers.arc.arcs, checked against a dense sampling of the circle."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bintrack.trackers.arc.arcs import TOL, Arc, ArcSet, depth_extreme, overlap_matrix
from bintrack.geometry import TWO_PI

# Sample points offset from any "nice" angle so they do not land on generated endpoints.
SAMPLES = (np.arange(20_000) + 0.5) * TWO_PI / 20_000 + 1.234e-6
STEP = TWO_PI / len(SAMPLES)

angle = st.floats(-10.0, 10.0, allow_nan=False)
length = st.floats(0.0, TWO_PI, allow_nan=False)
arc_sets = st.lists(st.tuples(angle, length), max_size=4).map(ArcSet)


def mask(s: ArcSet) -> np.ndarray:
    return s.contains(SAMPLES, tol=0.0)


def measure(m: np.ndarray) -> float:
    return m.sum() * STEP


def same(m1: np.ndarray, m2: np.ndarray) -> bool:
    # disagreement only within a couple of samples of each endpoint (rounding at boundaries)
    return np.count_nonzero(m1 != m2) <= 16


def well_formed(s: ArcSet) -> bool:
    starts = [a.start for a in s]
    ok = all(0.0 <= a.start < TWO_PI and TOL < a.length <= TWO_PI for a in s)
    if len(s) > 1:
        ends = [a.start + a.length for a in s]
        # disjoint and not touching, in order, the last not reaching round onto the first
        ok &= all(ends[k] < starts[k + 1] for k in range(len(s) - 1))
        ok &= ends[-1] - TWO_PI < starts[0]
    return ok


@settings(max_examples=150, deadline=None)
@given(arc_sets, arc_sets)
def test_operations_match_pointwise_sets(a, b):
    ma, mb = mask(a), mask(b)
    for result, expected in ((a & b, ma & mb), (a | b, ma | mb), (a - b, ma & ~mb), (~a, ~ma)):
        assert well_formed(result)
        assert same(mask(result), expected)
        assert result.length == pytest.approx(measure(expected), abs=20 * STEP)


@settings(max_examples=150, deadline=None)
@given(arc_sets, arc_sets, arc_sets)
def test_identities(a, b, c):
    assert (a & b).issubset(a)
    assert a.issubset(a | b)
    assert (a - b).length + (a & b).length == pytest.approx(a.length, abs=1e-7)
    assert ~(a | b) == (~a & ~b)
    assert ~(a & b) == (~a | ~b)
    assert a - (b | c) == (a - b) - c
    assert (a & (b | c)) == ((a & b) | (a & c))
    assert (~~a) == a


@settings(max_examples=100, deadline=None)
@given(arc_sets, angle)
def test_nearest_is_nearest(a, theta):
    if a.is_empty:
        with pytest.raises(ValueError):
            a.nearest(theta)
        return
    best = a.nearest(theta)
    assert best in a.arcs
    assert all(best.distance(theta) <= other.distance(theta) + 1e-12 for other in a)
    assert best.distance(theta) == 0.0 or not a.contains(theta)


def test_wrap_around_and_full_circle():
    across = ArcSet.between(5.5, 0.5)  # through 0
    assert len(across) == 1 and across.length == pytest.approx(0.5 + TWO_PI - 5.5)
    assert across.contains(0.0) and across.contains(6.0) and not across.contains(3.0)
    assert across.arcs[0].midpoint == pytest.approx((5.5 + (0.5 + TWO_PI - 5.5) / 2) % TWO_PI)
    full = ArcSet.full()
    assert full.is_full and full.length == pytest.approx(TWO_PI)
    assert (full - full).is_empty and (~ArcSet()).is_full
    assert (full & across) == across
    # two pieces meeting at 0 become one arc
    joined = ArcSet([(0.0, 1.0), (TWO_PI - 1.0, 1.0)])
    assert len(joined) == 1 and joined.arcs[0].start == pytest.approx(TWO_PI - 1.0)
    assert ArcSet.centred(1.0, 4.0).is_full


def test_touching_arcs_meet_in_nothing_and_fig3_cases():
    a, b = ArcSet.between(0.0, 1.0), ArcSet.between(1.0, 2.0)
    assert (a & b).is_empty
    assert (a | b) == ArcSet.between(0.0, 2.0) and len(a | b) == 1
    # Fig. 3(a): ∠1o3 & ∠2o4 = ∠2o3 ; (b) one inside the other ; (c) ∠1o3 − ∠2o4 = ∠1o2
    a13, a24 = ArcSet.between(0.2, 1.4), ArcSet.between(0.8, 2.0)
    assert (a13 & a24) == ArcSet.between(0.8, 1.4)
    assert (a13 & ArcSet.between(0.5, 1.0)) == ArcSet.between(0.5, 1.0)
    assert (a13 - a24) == ArcSet.between(0.2, 0.8)
    # (d): the result splits into ∠1o2 and ∠3o4
    split = ArcSet.between(0.2, 2.0) - ArcSet.between(0.8, 1.4)
    assert len(split) == 2
    assert split.nearest(0.1) == Arc(0.2, pytest.approx(0.6))
    assert split.nearest(1.6).start == pytest.approx(1.4)
    assert split.longest().start == pytest.approx(1.4)
    # a difference that only leaves slivers below TOL is empty
    assert (ArcSet.between(1.0, 2.0) - ArcSet.between(1.0 + 1e-12, 2.0 - 1e-12)).is_empty


def test_overlap_matrix_and_depth():
    starts = np.array([0.0, 0.5, 2.0, 6.0])
    lengths = np.array([1.0, 1.0, 0.5, 0.5])  # the last wraps to 0.217
    meets = overlap_matrix(starts, lengths)
    assert meets.tolist() == [
        [True, True, False, True],
        [True, True, False, False],
        [False, False, True, False],
        [True, False, False, True],
    ]
    assert overlap_matrix([0.0, 1.0], [1.0, 1.0]).tolist() == [[True, False], [False, True]]  # touching
    sets = [ArcSet([(s, l)]) for s, l in zip(starts, lengths)]
    assert depth_extreme(sets, ArcSet.full(), deepest=True) == (sets[0] & sets[1]) | (sets[0] & sets[3])
    assert depth_extreme(sets, ArcSet.between(0.0, 1.0), deepest=False) == ArcSet.between(6.0 + 0.5 - TWO_PI, 0.5)
