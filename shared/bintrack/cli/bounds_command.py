"""``bintrack bounds``: the analytic accuracy limits of the arc tracker (paper 001 §4).

Prints δ (eq. 10), ε (eq. 20), the nearly-uniform interval c/(ρR) (eqs. 21-23) and the eq. 24
figure for ``--nodes N`` sensors of range ``--range R`` on a domain of ``--area A`` units².
Angles are radians on the sensing circle; the distance beside each is the angle × R (δ and ε are
already the accuracy -- the half of the shortest combined arc -- see :mod:`bintrack.trackers.arc.bounds`).
With the defaults (the §4 example: N 800, A 400, R 1) the paper's values are shown alongside.
"""

from __future__ import annotations

import argparse
import math

from bintrack.trackers.arc import bounds
from bintrack.argtypes import int_at_least, positive_float
from bintrack.errors import CommandError

DEFAULT_NODES = 800
DEFAULT_AREA = 400.0
DEFAULT_RANGE = 1.0
#: the paper's §4 figures for the default setting (printed for comparison, never used in the maths)
PAPER = {"delta": 0.261, "epsilon": 0.155, "eq24_L": 0.278, "eq24": 0.139, "simulation": 0.135}
#: beyond this many expected sensing neighbours the §4 sums are pointless (use the c/(ρR) law)
MAX_MEAN_NEIGHBOURS = 200.0




def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--nodes", type=int_at_least(2), default=DEFAULT_NODES, metavar="N",
                        help=f"number of sensors (default {DEFAULT_NODES})")
    parser.add_argument("--area", type=positive_float, default=DEFAULT_AREA, metavar="A",
                        help=f"area of the domain in units² (default {DEFAULT_AREA:g}, i.e. 20 × 20)")
    parser.add_argument("--range", dest="sensing_range", type=positive_float, default=DEFAULT_RANGE,
                        metavar="R", help=f"sensing range in units (default {DEFAULT_RANGE:g})")


def run(args: argparse.Namespace) -> int:
    n, area, r = args.nodes, args.area, args.sensing_range
    if area <= 2.0 * math.pi * r * r:
        raise CommandError(f"too dense: the area {area:g} must exceed 2πR² = {2 * math.pi * r * r:.4g} (eq. 12)")
    mean_k = (n - 1) * bounds.p_sense(area, r)
    if mean_k > MAX_MEAN_NEIGHBOURS:
        raise CommandError(f"too dense: {mean_k:.0f} sensing neighbours on average (at most "
                           f"{MAX_MEAN_NEIGHBOURS:g}); the error is then ≈ c/(ρR) with 1/2 < c < π/(2+π)")
    b = bounds.compute(n, area, r)
    paper = (n, area, r) == (DEFAULT_NODES, DEFAULT_AREA, DEFAULT_RANGE)

    def ref(key: str) -> str:
        return f"   paper {PAPER[key]:.3f}" if paper else ""

    lo, hi = b.c_interval
    rad_lo, rad_hi = bounds.uniform_bounds_rad(b.rho_n)
    print(f"bintrack bounds: N = {n} nodes, area {area:g} units², range R = {r:g}  (paper 001 §4, ideal binary model)")
    print(f"  density ρ = N/A = {n / area:.4g} per unit², ρ_n = ρR² = {b.rho_n:.4g}; "
          f"mean sensing neighbours (N−1)πR²/A = {b.mean_sensing_neighbours:.3f}, k_max = {b.k_max}")
    print("  angles in radians on the sensing circle; distance = angle × R (already half the combined arc)")
    print(f"  δ   eq. 10, sensing neighbours only     {b.delta:.4f} rad = {b.delta * r:.4g} units{ref('delta')}")
    print(f"  ε   eq. 20, + non-sensing neighbours    {b.epsilon:.4f} rad = {b.epsilon * r:.4g} units{ref('epsilon')}")
    print(f"      improvement 1 − ε/δ                 {100 * (1 - b.epsilon / b.delta):.1f} %"
          + ("   paper ≈ 40 %" if paper else ""))
    print(f"  nearly uniform, k = πρ_n − 1 = {b.uniform_k:.3f}: δ_k = {b.uniform_delta:.4f} rad "
          f"= {b.uniform_delta * r:.4g} units")
    print(f"  c/(ρR), 1/2 < c < π/(2+π), eqs. 21-23  [{lo:.4g}, {hi:.4g}] units = [{rad_lo:.4f}, {rad_hi:.4f}] rad")
    if b.uniform_k < 1:
        print("      (eqs. 21-23 assume k ≥ 1, i.e. ρ_n ≥ 2/π; the upper bound need not hold here)")
    print(f"  eq. 24 ≈ L/2, L = c_mid/ρ_n = {b.eq24_L:.4f} rad  {b.eq24:.4f} rad = {b.eq24 * r:.4g} units"
          + (f"   paper {PAPER['eq24']:.3f} (L {PAPER['eq24_L']:.3f})" if paper else ""))
    if paper:
        print(f"  simulation (§4, arc tracker): paper {PAPER['simulation']:.3f} rad -- not computed here")
    return 0
