"""Analytic accuracy limits of the arc tracker under the ideal binary sensing model.

Paper 001 §4 ("Fundamental performance limits under ideal binary sensing model", eqs. 5-24),
DESIGN §8.1. ``N`` sensors of sensing range ``R`` are deployed uniformly over a domain of area
``A_d``. The paper sets ``R = 1``; here every formula is written for a general ``R`` by measuring
areas in units of ``R²`` (``π/A_d`` becomes ``πR²/A_d``, ``‖W‖ = R²(L + sin L)``), so angles are
the same as in the paper for the same ``A_d/R²``.

Units: every angle (``x``, ``t``, ``L``, ``δ``, ``ε``) is in **radians** on the sensing circle
of the node whose boundary the target crosses; the matching distance along that circle is the
angle times ``R`` (with ``R = 1`` the two coincide, as in the paper).

Reading choices (the ones that reproduce the paper's figures 0.261 and 0.155 for
``N = 800, A_d = 400, R = 1``):

* ``δ_k`` (eq. 11) is the mean arc from the target ``T`` to the *closest* intersection point
  ``P`` on one side of ``T`` -- i.e. already the half of the shortest combined arc. ``δ`` (eq. 10)
  is therefore the accuracy itself: the paper compares its ``ε`` with "0.270/2 = 0.135" from
  simulation (half the combination angle), not with 0.270. No extra factor 1/2 is applied.
* ``P_k`` (eq. 5) is evaluated with ``scipy.stats.binom.pmf(k, N-1, πR²/A_d)``, which is the same
  number as eq. 5 but stable for any ``N``; the recursion of eqs. 6-7 (and 13-15 for ``P'_k``) is
  only the paper's way of computing it and is not used.
* ``k_max`` follows the paper, ``P_{kmax+1} < 0.1 % ≤ P_{kmax}``, searched upwards from the mode;
  ``k'_max`` likewise. Terms below the mode whose probability is below 1e-13 are skipped (they
  contribute nothing at double precision), so the sums are the paper's sums from 0.
* In eq. 20 the non-sensing neighbours act on the half-arc ``AT`` of length ``L = δ_k`` (the
  average shortest arc ``AB`` has length ``2L``), so ``‖W‖ = R²(δ_k + sin δ_k)`` -- *not*
  ``L = δ_k/2`` (that reading gives ε ≈ 0.097).
* "Considering k_sensing values ranging from 1 to 16": ``k_sensing`` counts the node ``X`` plus
  its ``k`` sensing neighbours, ``k_sensing = k + 1``; with ``k = 0 … k_max = 15`` this is exactly
  1 … 16, so the paper's range is the ``k_max`` rule again.
* The accuracy ``ε`` is the *remaining* arc ``Σ_j P'_j δ'_j(δ_k)`` -- the right-hand side of
  eq. 20. The left-hand ``Σ_k P_k δ'(δ_k)`` with ``δ'`` of eq. 18 (the mean *cut-off* arc
  ``L − Σ_j P'_j δ'_j``) gives ≈ 0.106, not the paper's 0.155; ``δ'_j`` of eq. 19 is the remaining
  arc for ``j`` cutting nodes (``E[max] = L − ∫ P'(t)^j dt``), so eq. 18's two sides are the
  cut-off and the right-hand side of eq. 20 is what is left, the accuracy.
* Nearly uniform deployment (eqs. 21-24): ``ρ_n = N R²/A_d`` sensors per ``R²``; ``k = πρ_n − 1``
  (generally not an integer; eq. 11 is evaluated at that real ``k``). The error bounds
  ``π/(2(k+1)) < δ_k < π²/((2+π)(k+1))`` radians are ``c/ρ_n`` radians = ``c/(ρR)`` distance,
  ``1/2 < c < π/(2+π)``. For eq. 24 the paper takes ``c`` in the middle of that interval,
  ``L = c_mid/ρ_n`` (0.278 for ρ_n = 2), and the accuracy ``(1 + L²/2 − cos L)/(L + sin L)``
  (0.139).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import quad
from scipy.stats import binom

#: the paper's truncation threshold for ``k_max`` and ``k'_max`` (0.1 %)
PAPER_THRESHOLD = 1e-3
#: probabilities below this are skipped when summing from k = 0 (no effect at double precision)
_NEGLIGIBLE = 1e-13
#: the interval of ``c`` in ``c/(ρR)`` (eqs. 21-23)
C_LOW = 0.5
C_HIGH = math.pi / (2.0 + math.pi)
C_MID = 0.5 * (C_LOW + C_HIGH)


def _quad(func, a: float, b: float) -> float:
    value, _ = quad(func, a, b, epsabs=1e-13, epsrel=1e-10, limit=200)
    return float(value)


def _check_setting(nodes: int, area: float, sensing_range: float) -> None:
    if int(nodes) != nodes or nodes < 2:
        raise ValueError(f"need at least 2 nodes, got {nodes!r}")
    if not (math.isfinite(area) and area > 0 and math.isfinite(sensing_range) and sensing_range > 0):
        raise ValueError("area and sensing range must be positive numbers")
    # eq. 12 divides by A_d - πR² and needs ‖W‖ ≤ R²(π + sin π) = πR² below it
    if area <= 2.0 * math.pi * sensing_range ** 2:
        raise ValueError(f"domain area {area:g} must exceed 2πR² = {2 * math.pi * sensing_range ** 2:g}")


# ---------------------------------------------------------------------------- sensing neighbours

def p_sense(area: float, sensing_range: float = 1.0) -> float:
    """Probability that one other node senses the target: ``πR²/A_d`` (eq. 5 with R = 1)."""
    return math.pi * sensing_range ** 2 / area


def prob_k(k, nodes: int, area: float, sensing_range: float = 1.0):
    """``P_k`` (eq. 5): probability that exactly ``k`` of the other ``N − 1`` nodes sense the target.

    ``C(N−1, k) (πR²/A_d)^k (1 − πR²/A_d)^(N−k−1)``, evaluated with ``scipy.stats.binom.pmf``
    (stable for any N) instead of the recursion of eqs. 6-7.
    """
    return binom.pmf(k, nodes - 1, p_sense(area, sensing_range))


def prob_arc(x):
    """``P(x) = (x + sin x)/π`` (eq. 8; printed as "x + sin(x)/π"): probability that the arc ``PT``
    from the target to one sensing neighbour's intersection point is ≤ ``x`` radians,
    ``0 ≤ x ≤ π``; it is ``‖area A‖/‖circle T‖`` with ``‖area A‖ = R²(x + sin x)``."""
    return (np.asarray(x, dtype=float) + np.sin(x)) / math.pi


def prob_shortest_arc(x, k: float):
    """``P_s(x) = 1 − (1 − P(x))^k`` (eq. 9): the shortest of ``k`` such arcs is ≤ ``x`` rad."""
    return 1.0 - (1.0 - prob_arc(x)) ** k


def delta_k(k: float) -> float:
    """``δ_k`` (eq. 11), radians: mean shortest arc from the target to the closest intersection
    point with ``k`` sensing neighbours, ``∫_0^π (1 − (x + sin x)/π)^k dx``. ``δ_0 = π``.
    ``k`` may be real (the nearly-uniform case, eq. 21)."""
    if k < 0:
        raise ValueError(f"k must be >= 0, got {k}")
    return _quad(lambda x: (1.0 - (x + math.sin(x)) / math.pi) ** k, 0.0, math.pi)


def _k_range(pmf, mode: int, upper: int, threshold: float) -> tuple[int, int]:
    """(k_low, k_max): ``k_max`` is the first k ≥ mode with ``pmf(k+1) < threshold``
    (``P_{kmax+1} < threshold ≤ P_{kmax}``); ``k_low`` the smallest k with non-negligible mass."""
    k_max = mode
    while k_max < upper and pmf(k_max + 1) >= threshold:
        k_max += 1
    k_low = mode
    while k_low > 0 and pmf(k_low - 1) >= _NEGLIGIBLE:
        k_low -= 1
    return k_low, k_max


def k_max(nodes: int, area: float, sensing_range: float = 1.0, threshold: float = PAPER_THRESHOLD) -> int:
    """``k_max`` of eq. 10: ``P_{kmax+1} < 0.1 % ≤ P_{kmax}`` (searched upwards from the mode)."""
    p = p_sense(area, sensing_range)
    mode = int(math.floor(nodes * p))  # mode of Binomial(N−1, p)
    return _k_range(lambda k: prob_k(k, nodes, area, sensing_range), min(mode, nodes - 1),
                    nodes - 1, threshold)[1]


def delta(nodes: int, area: float, sensing_range: float = 1.0, threshold: float = PAPER_THRESHOLD) -> float:
    """``δ`` (eq. 10), radians: mean accuracy using only neighbours that sense the target,
    ``Σ_{k=0}^{kmax} P_k δ_k``. Distance along the circle: ``δ·R``."""
    _check_setting(nodes, area, sensing_range)
    return _delta_terms(nodes, area, sensing_range, threshold)[2]


def _delta_terms(nodes, area, sensing_range, threshold):
    p = p_sense(area, sensing_range)
    mode = min(int(math.floor(nodes * p)), nodes - 1)
    k_low, k_hi = _k_range(lambda k: prob_k(k, nodes, area, sensing_range), mode, nodes - 1, threshold)
    ks = np.arange(k_low, k_hi + 1)
    pk = prob_k(ks, nodes, area, sensing_range)
    dk = np.array([delta_k(int(k)) for k in ks])
    return ks, pk, float(np.dot(pk, dk)), dk


# ------------------------------------------------------------------------ non-sensing neighbours

def area_w(L: float, sensing_range: float = 1.0) -> float:
    """``‖area W‖ = R²(L + sin L)`` (eq. 12): where a non-sensing node cuts the half-arc ``AT``
    of length ``L`` radians."""
    return sensing_range ** 2 * (L + math.sin(L))


def prob_k_nonsensing(k, L: float, nodes: int, area: float, k_sensing: int, sensing_range: float = 1.0):
    """``P'_k`` (eq. 12): probability that exactly ``k`` of the ``N − k_sensing`` non-sensing nodes
    fall in ``W``, ``Binomial(N − k_sensing, ‖W‖/(A_d − πR²))``, via ``scipy.stats.binom.pmf``
    (instead of the recursion of eqs. 13-15). ``L`` in radians."""
    q = area_w(L, sensing_range) / (area - math.pi * sensing_range ** 2)
    return binom.pmf(k, nodes - k_sensing, q)


def prob_cut(t, L: float):
    """``P'(t) = (t + sin t)/(L + sin L)`` (eq. 16): probability that the arc ``PA`` cut by one
    non-sensing node in ``W`` is ≤ ``t`` radians, ``0 ≤ t ≤ L``."""
    return (np.asarray(t, dtype=float) + np.sin(t)) / (L + math.sin(L))


def delta_prime_j(j: int, L: float) -> float:
    """``δ'_j(L)`` (eq. 19), radians: ``∫_0^L (t + sin t)^j dt / (L + sin L)^j``, the mean arc left of
    the half-arc ``L`` after the longest cut by ``j`` non-sensing nodes (``L − E[max]``, eq. 17).
    ``δ'_0 = L``."""
    w = L + math.sin(L)
    return _quad(lambda t: ((t + math.sin(t)) / w) ** j, 0.0, L)


def remaining_arc(L: float, nodes: int, area: float, k_sensing: int, sensing_range: float = 1.0,
                  threshold: float = PAPER_THRESHOLD) -> float:
    """``Σ_{j=0}^{k'max} P'_j δ'_j(L)`` (inner sum of eq. 20), radians: the mean half-arc left after
    non-sensing neighbours cut a half-arc of ``L``. Equals ``L − δ'(L)`` of eq. 18."""
    n = nodes - k_sensing
    if n <= 0:
        return L
    q = area_w(L, sensing_range) / (area - math.pi * sensing_range ** 2)
    pmf = lambda j: prob_k_nonsensing(j, L, nodes, area, k_sensing, sensing_range)  # noqa: E731
    mode = min(int(math.floor((n + 1) * q)), n)
    j_low, j_hi = _k_range(pmf, mode, n, threshold)
    return float(sum(pmf(j) * delta_prime_j(j, L) for j in range(j_low, j_hi + 1)))


def epsilon(nodes: int, area: float, sensing_range: float = 1.0, threshold: float = PAPER_THRESHOLD) -> float:
    """``ε`` (eq. 20), radians: mean accuracy using sensing and non-sensing neighbours,
    ``Σ_{k=0}^{kmax} P_k Σ_{j=0}^{k'max} P'_j δ'_j(δ_k)`` with ``L = δ_k`` and
    ``k_sensing = k + 1`` (node X and its k sensing neighbours: 1 … 16 in the paper's example).
    Distance along the circle: ``ε·R``."""
    _check_setting(nodes, area, sensing_range)
    return _epsilon_from(nodes, area, sensing_range, threshold, *_delta_terms(nodes, area, sensing_range, threshold))


def _epsilon_from(nodes, area, sensing_range, threshold, ks, pk, _delta, dk) -> float:
    return float(sum(p * remaining_arc(d, nodes, area, int(k) + 1, sensing_range, threshold)
                     for k, p, d in zip(ks, pk, dk)))


# ------------------------------------------------------------------------------ nearly uniform

def density_per_r2(nodes: int, area: float, sensing_range: float = 1.0) -> float:
    """``ρ_n``: mean number of sensors per ``R × R`` square, ``N R²/A_d`` (= ρR² with ρ = N/A_d)."""
    return nodes * sensing_range ** 2 / area


def uniform_k(rho_n: float) -> float:
    """``k = πρ_n − 1``: sensing neighbours of the node whose boundary is crossed (§4, before eq. 21)."""
    return math.pi * rho_n - 1.0


def uniform_delta(rho_n: float) -> float:
    """``δ_k`` of eq. 11 at the nearly-uniform ``k = πρ_n − 1`` (radians; real ``k``)."""
    return delta_k(max(uniform_k(rho_n), 0.0))


def uniform_bounds_rad(rho_n: float) -> tuple[float, float]:
    """Eqs. 21-23 in radians: ``π/(2(k+1)) < δ_k < π²/((2+π)(k+1))`` with ``k + 1 = πρ_n``,
    i.e. ``(1/2)/ρ_n`` and ``(π/(2+π))/ρ_n``."""
    return C_LOW / rho_n, C_HIGH / rho_n


def uniform_bounds_distance(density: float, sensing_range: float = 1.0) -> tuple[float, float]:
    """The error ``c/(ρR)`` with ``1/2 < c < π/(2+π)`` (after eq. 23), in distance units;
    ``ρ = N/A_d`` sensors per unit²."""
    return C_LOW / (density * sensing_range), C_HIGH / (density * sensing_range)


def eq24_half_arc(rho_n: float, c: float = C_MID) -> float:
    """``L = c/ρ_n`` radians (before eq. 24; paper: L ≥ 1/(2ρ_n), and with ``c`` in the middle of
    the interval, L = 0.278 for ρ_n = 2)."""
    return c / rho_n


def eq24_accuracy(L: float) -> float:
    """Eq. 24, radians: with one non-sensing node in ``W`` (``P'_1 = 1``) the remaining half-arc is
    ``∫_0^L (t + sin t) dt/(L + sin L) = (1 + L²/2 − cos L)/(L + sin L) ≈ L/2``."""
    return (1.0 + 0.5 * L * L - math.cos(L)) / (L + math.sin(L))


# ------------------------------------------------------------------------------------ summary

@dataclass(frozen=True)
class Bounds:
    """All §4 figures for one setting. Angles in radians; ``*_distance`` = angle × R."""

    nodes: int
    area: float
    sensing_range: float
    mean_sensing_neighbours: float  # (N − 1)πR²/A_d
    k_max: int
    delta: float  # eq. 10
    epsilon: float  # eq. 20
    rho_n: float  # N R²/A_d
    uniform_k: float  # πρ_n − 1
    uniform_delta: float  # eq. 11 at k = πρ_n − 1
    c_interval: tuple[float, float]  # c/(ρR), distance units (eqs. 21-23)
    eq24_L: float  # c_mid/ρ_n, radians
    eq24: float  # eq. 24, radians


def compute(nodes: int, area: float, sensing_range: float = 1.0, threshold: float = PAPER_THRESHOLD) -> Bounds:
    """Every §4 figure for ``N`` nodes on ``A_d`` units² with sensing range ``R``."""
    _check_setting(nodes, area, sensing_range)
    terms = _delta_terms(nodes, area, sensing_range, threshold)
    eps = _epsilon_from(nodes, area, sensing_range, threshold, *terms)
    rho_n = density_per_r2(nodes, area, sensing_range)
    L = eq24_half_arc(rho_n)
    return Bounds(
        nodes=nodes, area=area, sensing_range=sensing_range,
        mean_sensing_neighbours=(nodes - 1) * p_sense(area, sensing_range),
        k_max=int(terms[0][-1]), delta=terms[2], epsilon=eps,
        rho_n=rho_n, uniform_k=uniform_k(rho_n), uniform_delta=uniform_delta(rho_n),
        c_interval=uniform_bounds_distance(nodes / area, sensing_range),
        eq24_L=L, eq24=eq24_accuracy(L),
    )
