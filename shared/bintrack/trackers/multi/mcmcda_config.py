"""The parameters of online MCMCDA (paper 004 §IV): the model of eq. 3, the Kalman filter, the
sampler, and the identity policy."""

from __future__ import annotations

from dataclasses import dataclass, replace

from bintrack.errors import TrackerConfigError


@dataclass(frozen=True)
class MCMCDAConfig:
    """Parameters of the model (eq. 3, Kalman filter) and of the online sampler.

    Lengths are in the reports' units; the defaults are for metres (people walking through PIR
    sensors of about 8 m range), and :meth:`in_units` converts them to other units."""

    window: int = 5
    """sliding-window length, scans"""
    n_mc: int = 500
    """Metropolis–Hastings iterations per scan and chain"""
    chains: int = 4
    """chains per scan, each of n_mc iterations from the previous MAP; the MAP over them is kept
    (4 chosen on the tuning half of ``benchmarks/multi_target.py``: fewer identity switches and
    half the seed spread of one chain; it takes about 4 × one chain's time)"""
    seed: int = 0
    """seed of the sampler's random stream"""
    process_noise: float = 0.02
    """q: white-acceleration spectral density of the constant-velocity model, units²/s³ (0.02
    chosen on the tuning half of ``benchmarks/multi_target.py``: people walk with few sharp
    turns; it was 0.1)"""
    extra_variance: float = 4.0
    """added to each report's variance per axis, units² (a cluster's spread understates the
    error of its centre)"""
    initial_speed: float = 1.5
    """standard deviation of a new track's velocity per axis, units/s"""
    pd: float = 0.85
    """probability that a present target yields a report in a scan"""
    false_alarm_rate: float = 3e-4
    """λ_f: false reports per unit area per scan"""
    birth_rate: float = 1e-4
    """λ_b: new targets per unit area per scan"""
    termination: float = 0.05
    """p_z: probability that a target disappears between scans"""
    max_speed: float = 3.0
    """v̄: fastest target, units/s (gates which reports may follow each other in a track)"""
    gate_sigmas: float = 3.0
    """added to v̄·Δt in that gate: this many standard deviations of the two positions' noise"""
    max_misses: int = 3
    """d̄: consecutive scans a track may go unreported"""
    stop: float = 0.3
    """γ: probability that an extension proposal stops after each added report"""
    min_reports: int = 2
    """reports a track needs (fixed and in the window) before it is published"""
    coast: int = 1
    """scans a published track is predicted past its last report before it is dropped"""
    smooth_noise: float | None = None
    """q of the fixed-lag smoother's Rauch–Tung–Striebel pass (:mod:`.fixed_lag`), units²/s³;
    None: ``process_noise``, the chain's own. Real PIR (:mod:`.pir_settings`) uses 0.1 m²/s³"""
    exit_depth: float | None = 1.0
    """a published track unreported in a scan is not shown predicted (``coast``) when its
    prediction lies less than this far (units; negative: outside) inside the sensor field, the
    sensors' convex hull: there a person no sensor reports has most likely left (1 m chosen on
    the tuning half of ``benchmarks/multi_target.py``); None: coasted anywhere"""
    entry_depth: float | None = None
    """a report of this scan that no track of the MAP holds, lies less than this far (units)
    inside the sensor field and in no live track's gate is published at once, as a person
    entering (a track needs two reports), if its evidence is at least ``entry_gain``; None (the
    default): a track is first shown at its second report. Tried at 2 m on
    ``benchmarks/multi_target.py``: lower GOSPA on both halves, more identity switches on the
    held-out one (docs/peers.md); real PIR (:mod:`.pir_settings`) uses 1 m"""
    entry_gain: float = 10.0
    """nats of evidence (the report's weight, fitted fusion) a report needs to be published as an
    entry (10 chosen on the tuning half: 8 let more clutter through)"""
    reidentify: float = 8.0
    """s: a new track takes the identity of a track last shown at most this long ago (and
    before its first report), if that report lies within ``gate_sigmas`` of the old track's
    prediction"""
    birth_edge: float | None = None
    """real PIR: people are born within this distance (units) of ``birth_area``'s edge (the
    room's doors are on its walls); None: anywhere (the paper's uniform birth)"""
    birth_area: tuple[float, float, float, float] | None = None
    """xmin, ymin, xmax, ymax (units) of the room for ``birth_edge``; None: no room"""
    birth_doors: tuple[tuple[float, float], ...] | None = None
    """(x, y) of the room's doors (units, the deployment's floor plan): people are born within
    ``birth_edge`` of a door rather than of ``birth_area``'s edge; None: doors anywhere on the walls"""
    birth_inside: float = 0.1
    """λ_b farther than ``birth_edge`` from the edge, as a fraction of λ_b near it"""
    still_misses: int = 0
    """scans a track may go unreported and then go on from where it was last reported, as a
    target that stood still (a PIR sees motion: a person standing fades out); longer than d̄
    only, for a track last reported at least ``still_depth`` inside the sensor field; 0: off"""
    still_depth: float = 1.0
    """units: how far inside the sensor field (the sensors' convex hull) a track must end to be
    taken for a target that stood still (``still_misses``); nearer the edge it has most likely left"""
    still_reach: float = 1.5
    """units: how far from a still target's last report its next one may lie (plus
    ``gate_sigmas`` σ of the two positions); its position's spread is half this"""
    still_pd: float = 0.05
    """probability that a still target yields a report in a scan"""
    still_prior: float = 0.01
    """probability that a target unreported for over d̄ + 1 scans stood still rather than ended
    (0.01 chosen with real PIR on the selection sets of ``benchmarks/real_pir_choices.py``: 0.05
    and 0.2 traded people more in a crowd)"""
    adapt_rates: int = 0
    """scans of settled evidence behind online estimates of ``pd`` and ``false_alarm_rate``
    (:mod:`.mcmcda_rates`; the configured values are their prior); 0: the configured values
    throughout"""

    def in_units(self, metres_per_unit: float) -> MCMCDAConfig:
        """This configuration, read as metres and seconds, in units of ``metres_per_unit`` m:
        speeds and the report variance scale by 1/metres_per_unit (squared for variances and
        q), and the rates per unit area by metres_per_unit²."""
        k = 1.0 / metres_per_unit
        return replace(self, process_noise=self.process_noise * k * k, extra_variance=self.extra_variance * k * k,
                       smooth_noise=None if self.smooth_noise is None else self.smooth_noise * k * k,
                       initial_speed=self.initial_speed * k, max_speed=self.max_speed * k,
                       false_alarm_rate=self.false_alarm_rate / (k * k), birth_rate=self.birth_rate / (k * k),
                       exit_depth=None if self.exit_depth is None else self.exit_depth * k,
                       entry_depth=None if self.entry_depth is None else self.entry_depth * k,
                       birth_edge=None if self.birth_edge is None else self.birth_edge * k,
                       still_depth=self.still_depth * k, still_reach=self.still_reach * k,
                       birth_area=None if self.birth_area is None else tuple(v * k for v in self.birth_area),
                       birth_doors=None if self.birth_doors is None else tuple((x * k, y * k) for x, y in self.birth_doors))

    def __post_init__(self):
        checks = [("window", self.window >= 2), ("n_mc", self.n_mc >= 1), ("chains", self.chains >= 1), ("max_misses", self.max_misses >= 0),
                  ("pd", 0 < self.pd < 1), ("termination", 0 < self.termination < 1), ("stop", 0 < self.stop < 1),
                  ("false_alarm_rate", self.false_alarm_rate > 0), ("birth_rate", self.birth_rate > 0),
                  ("max_speed", self.max_speed > 0), ("initial_speed", self.initial_speed > 0),
                  ("process_noise", self.process_noise > 0), ("extra_variance", self.extra_variance >= 0),
                  ("gate_sigmas", self.gate_sigmas > 0), ("coast", self.coast >= 0), ("smooth_noise", self.smooth_noise is None or self.smooth_noise > 0), ("reidentify", self.reidentify >= 0), ("min_reports", self.min_reports >= 2),
                  ("adapt_rates", self.adapt_rates >= 0), ("entry_gain", self.entry_gain >= 0),
                  ("still_misses", self.still_misses >= 0), ("still_reach", self.still_reach > 0),
                  ("still_pd", 0 < self.still_pd < 1), ("still_prior", 0 < self.still_prior < 1)]
        bad = [name for name, ok in checks if not ok]
        if bad:
            raise TrackerConfigError(f"MCMCDA parameter out of range: {', '.join(f'{n}={getattr(self, n)}' for n in bad)}")

