"""Paper 001 §4: the analytic accuracy limits (``bintrack.trackers.arc.bounds``) and ``bintrack bounds``."""

from __future__ import annotations

import math

import pytest
from scipy.stats import binom

from bintrack.trackers.arc import bounds
from bintrack.cli.main import main

N, AREA, R = 800, 400.0, 1.0  # the §4 example: 800 nodes on 20 × 20, unit range


@pytest.fixture(scope="module")
def paper_setting() -> bounds.Bounds:
    return bounds.compute(N, AREA, R)


def test_paper_values_within_two_percent(paper_setting):
    b = paper_setting
    assert b.delta == pytest.approx(0.261, rel=0.02)
    assert b.epsilon == pytest.approx(0.155, rel=0.02)
    assert b.eq24_L == pytest.approx(0.278, rel=0.02)
    assert b.eq24 == pytest.approx(0.139, rel=0.02)
    # "k_sensing values ranging from 1 to 16": k_sensing = k + 1 for k = 0 … k_max
    assert b.k_max == 15
    # "improves the accuracy of localization by about 40 %"
    assert 1 - b.epsilon / b.delta == pytest.approx(0.40, abs=0.03)


def test_building_blocks():
    assert bounds.delta_k(0) == pytest.approx(math.pi)  # no sensing neighbour: half circle
    assert bounds.prob_arc(math.pi) == pytest.approx(1.0)  # eq. 8
    assert bounds.prob_arc(0.0) == pytest.approx(0.0)
    assert bounds.prob_k(3, N, AREA) == pytest.approx(binom.pmf(3, N - 1, math.pi / AREA))  # eq. 5
    L = 0.3
    assert bounds.delta_prime_j(0, L) == pytest.approx(L)  # eq. 19, nothing cuts
    assert bounds.delta_prime_j(1, L) == pytest.approx(bounds.eq24_accuracy(L))  # eq. 24 is j = 1
    assert bounds.prob_cut(L, L) == pytest.approx(1.0)  # eq. 16
    # δ_k falls with k; δ'_j(L) falls with j
    assert [bounds.delta_k(k) for k in range(5)] == sorted((bounds.delta_k(k) for k in range(5)), reverse=True)
    assert bounds.delta_prime_j(3, L) < bounds.delta_prime_j(2, L) < L


def test_delta_and_epsilon_fall_as_nodes_grow():
    ds = [bounds.delta(n, AREA) for n in (200, 400, 800, 1600)]
    es = [bounds.epsilon(n, AREA) for n in (200, 400, 800)]
    assert ds == sorted(ds, reverse=True) and len(set(ds)) == len(ds)
    assert es == sorted(es, reverse=True) and len(set(es)) == len(es)
    assert all(e < d for e, d in zip(es, ds))


def test_range_scaling_keeps_angles():
    """Areas are in units of R²: the same A/R² and N give the same angles."""
    assert bounds.delta(800, 400.0 * 9, 3.0) == pytest.approx(bounds.delta(800, 400.0, 1.0), rel=1e-9)


@pytest.mark.parametrize("rho_n", [1.0, 2.0, 5.0, 10.0])
def test_c_interval_brackets_nearly_uniform_delta(rho_n):
    lo, hi = bounds.uniform_bounds_rad(rho_n)  # eqs. 21-23, radians
    assert lo < bounds.uniform_delta(rho_n) < hi
    # the same in distance units, c/(ρR), for R = 2 (ρ = ρ_n/R²)
    r = 2.0
    dlo, dhi = bounds.uniform_bounds_distance(rho_n / r ** 2, r)
    assert dlo < bounds.uniform_delta(rho_n) * r < dhi


def test_cli_default_prints_paper_figures(capsys):
    assert main(["bounds"]) == 0
    out = capsys.readouterr().out
    for text in ("0.2613 rad", "paper 0.261", "0.1554 rad", "paper 0.155", "0.1393 rad", "paper 0.139",
                 "[0.25, 0.3055]"):
        assert text in out, text


def test_cli_other_setting_has_no_paper_column(capsys):
    assert main(["bounds", "--nodes", "400", "--area", "400", "--range", "1"]) == 0
    assert "paper" not in capsys.readouterr().out.replace("(paper 001", "")


@pytest.mark.parametrize("argv", [
    ["bounds", "--nodes", "0"],
    ["bounds", "--area", "-4"],
    ["bounds", "--range", "nan"],
    ["bounds", "--area", "5"],  # below 2πR²: too dense for eq. 12
    ["bounds", "--nodes", "100000"],  # hundreds of sensing neighbours: too dense
])
def test_cli_bad_option_exits_2(argv, capsys):
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err and "error" in err[-1]
