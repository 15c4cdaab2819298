"""Fusion and MCMCDA settings for real ceiling PIR sensors (a deployment whose disk sensors carry
the ``hold`` field that ``bintrack calibrate`` writes): footprints of about a metre rather than the
8 m of paper 004's outdoor PIR nodes, in a room of a few people.

The defaults of :class:`MCMCDAConfig` and :class:`FusionConfig` were chosen for paper 004's
setting; a deployment without ``hold`` keeps them exactly. For real PIR they change where the
defaults encode the 8 m footprint or the 60 m field (chosen on the r1-easy sequence of the
ceiling-PIR recording of Milan et al., ACCV 2014 workshops; reported on r1-medium):

* ``extra_variance``: a report's variance per axis grows with the footprint, (R/3)² (R the
  median fitted radius), rather than 4 m² for R = 8 m;
* ``pd``: about 0.6 of a scan's people yield a report with sensors of pd ≈ 0.6;
* ``birth_rate``: 1e-3 per m² and scan, people come and go through the doors of a small room;
* ``min_gain``: 2 nats, a target seen by one or two weak sensors still makes a report;
* ``threshold`` (n_d): 2 detections place a new target, not 3: a walker lights 1.6 sensors per
  sample on average (37 % of the time only one), so with 3 most people were never placed;
* ``soft_spread``: a report is the posterior mean and covariance of the position under Gaussian
  footprints, σ = R/2 per sensor (the Gaussian with the second moment of the fitted disk), over
  the detection pattern, misses included (:mod:`.soft_footprint`): a real sensor's firing rate
  falls smoothly with distance, 0.7 under it, 0.3 at 1–1.5 m, 0.1 at 1.5–2 m;
* ``expected_split_gain``: 8 nats, a track's blob is split into two people only on strong
  evidence (footprints of neighbouring sensors overlap, and one walker lights several);
* ``max_misses`` 5 (d̄): a PIR sees motion, and a person who slows down or stands fires fewer
  sensors; their track survives 2.5 s without a report;
* ``coast`` 2, not 1: a track is shown predicted for two scans past its last report (a second
  of a person no sensor reported); a lower count error and fewer identity switches on all five
  selection sets, better MOTA on four (docs/real_sensors.md, "Showing a track a second scan");
* ``exit_depth`` None: a track is coasted near the room's walls too, as before exits were
  added (they were chosen on paper 004's outdoor grid, where people leave across the field's
  edge, and not tried in the room);
* ``entry_depth`` 1 m, ``entry_gain`` 4 nats: a person is shown from their first report where
  they come in (a strong report the chain leaves false within 1 m of the sensors' hull or
  outside it, in no track's gate); the only change of four rounds that did better on all five
  selection sets (``benchmarks/real_pir_choices.py``), by half a MOTA point;
* ``chains`` 8, not 4: more of the sampler's search per scan, which a room of 43 sensors and a
  few people affords; better MOTA on all five selection sets (+0.2 to +2.3 points), the count
  error and GOSPA better on most (fifth round, docs/real_sensors.md);
* ``multiplicity`` False and ``expected_gain`` 1 nat: targets counted over the union of the
  footprints, and a track's target placed on a nat of support, as before issue 42's outdoor grid
  took each target detected on its own and 0 nats; tried in the room, that was better on the four
  simulated selection sets (MOTA +2 to +5 points) and worse on r1-easy (−4 points), the real one;
* ``evidence_reference`` None: the bars stay in fixed nats however clean the fitted sensors (the
  scaling was chosen on paper 004's outdoor grid, and not tried in the room);
* births: λ_b ten times lower farther than 1.5 m from the walls (``MCMCDAConfig.birth_edge``):
  people enter through the doors; where the deployment's floor plan names its doors, farther than
  1.5 m from them (``birth_doors``);
* ``process_noise`` 0.035 m²/s³, not 0.02: people in a room turn and slow down more often than
  walkers crossing paper 004's field; lower GOSPA on all five selection sets, better MOTA on four
  (docs/real_sensors.md, "The motion model's noise");
* ``still_misses`` 40 (20 s): a track that ends 1 m or more inside the sensors' hull may go on
  from where it was last reported, as a person who stood still and walked on (prior 0.01, a
  still person's report pd 0.05); better MOTA and GOSPA on all five selection sets, and more of
  the paused people of ``benchmarks/real_pir_stops.py`` keep their identity (docs/real_sensors.md,
  "A person who stands still");
* ``smooth_noise`` 0.1 m²/s³: with ``--lag``, the fixed-lag smoother's Rauch–Tung–Striebel pass
  (:mod:`.fixed_lag`) lets a person turn more freely than the chain's q of 0.035 does; better
  MOTA and GOSPA than the chain's own q on r1-easy, lower GOSPA on all five selection sets
  (docs/real_sensors.md, "A fixed-lag smoother");
* ``count_switch`` 0.02 per scan, ``count_threshold`` 1 and ``count_soft`` 0.9: a count of the
  people from how many sensors fire (:mod:`.firing_count`); while it holds more people than the
  fit placed, a target is sought on a single firing sensor, and kept if Gaussian footprints of
  0.9 × each fitted radius find it 2 nats of evidence given the others (a walker's far firings
  need no second person). The count error lower on all five selection sets (by 0.005 to 0.24),
  MOTA better on four (+2.0 to +3.5 points; r1-easy −0.1) (docs/real_sensors.md, "The count's
  people sought by the fit"; on r1-medium it changed little).
"""

from __future__ import annotations

import statistics
from dataclasses import replace

from bintrack.deployment_model import Deployment, DiskSensor
from bintrack.trackers.multi.fusion_config import FusionConfig
from bintrack.trackers.multi.mcmcda_config import MCMCDAConfig

FOOTPRINT_SIGMAS = 3.0
PIR_REPORT_PD = 0.6
PIR_BIRTH_RATE = 1e-3
PIR_MIN_GAIN = 2.0
PIR_SPLIT_GAIN = 8.0
PIR_EXPECTED_GAIN = 1.0
"""nats: the least support for a target where a track expects one"""
PIR_MULTIPLICITY = False
"""targets counted over the union of the footprints, eq. (4) as the paper has it"""
PIR_SHARED_SUPPORT = None
"""no evidence bar on shared copies: over the union of the footprints a second target in a blob
adds nothing, so the bar (made for ``FusionConfig.multiplicity``) would tell nothing"""
PIR_THRESHOLD = 2
PIR_SPREAD = 0.5
PIR_MAX_MISSES = 5
PIR_PROCESS_NOISE = 0.035
"""m²/s³: the white-noise acceleration of a person's constant-velocity model in a room"""
PIR_SMOOTH_NOISE = 0.1
"""m²/s³: the fixed-lag smoother's white-noise acceleration (``--lag``)"""
PIR_COAST = 2
"""scans a track is shown predicted past its last report"""
PIR_ENTRY_DEPTH = 1.0
"""m: a strong report this close to the sensors' hull (or outside it) is shown as a person coming in"""
PIR_ENTRY_GAIN = 4.0
PIR_STILL_MISSES = 40
"""scans (0.5 s) a person may stand still, unreported, and keep their track"""
PIR_CHAINS = 8
"""chains per scan: a room's MCMCDA is small, and twice paper 004's four chains found better
explanations on every selection set"""
PIR_COUNT_SWITCH = 0.02
"""chance per scan (0.5 s) that someone comes or goes, for the count from the firings"""
PIR_COUNT_SPREAD = 0.9
"""σ of the Gaussian footprints that judge a person the count asks for, × each fitted radius"""
DOOR_DEPTH = 1.5
"""m: people are born within this distance of the room's walls, or of its doors where the floor plan names them"""


def is_real_pir(deployment: Deployment) -> bool:
    """Whether the deployment's disk sensors are real PIR sensors (they state a ``hold``)."""
    return any(isinstance(s, DiskSensor) and s.hold is not None for s in deployment.sensors)


def pir_settings(deployment: Deployment, fusion: FusionConfig, config: MCMCDAConfig) -> tuple[FusionConfig, MCMCDAConfig]:
    """``fusion`` and ``config`` (metres) adapted to real PIR sensors; unchanged for other deployments."""
    if not is_real_pir(deployment):
        return fusion, config
    radius = statistics.median(s.range for s in deployment.sensors if isinstance(s, DiskSensor))
    radius_m = radius * deployment.metres_per_unit
    config = replace(config, extra_variance=(radius_m / FOOTPRINT_SIGMAS) ** 2, pd=PIR_REPORT_PD,
                     birth_rate=PIR_BIRTH_RATE, max_misses=PIR_MAX_MISSES, exit_depth=None,
                     entry_depth=PIR_ENTRY_DEPTH, entry_gain=PIR_ENTRY_GAIN, chains=PIR_CHAINS,
                     still_misses=PIR_STILL_MISSES, process_noise=PIR_PROCESS_NOISE, coast=PIR_COAST,
                     smooth_noise=PIR_SMOOTH_NOISE)
    if DOOR_DEPTH is not None:
        r = deployment.region
        m = deployment.metres_per_unit
        doors = tuple((x * m, y * m) for x, y in deployment.floor_plan.doors) if deployment.floor_plan else ()
        config = replace(config, birth_edge=DOOR_DEPTH, birth_area=(r.xmin * m, r.ymin * m, r.xmax * m, r.ymax * m),
                         birth_doors=doors or None)
    fusion = replace(fusion, min_gain=PIR_MIN_GAIN, expected_split_gain=PIR_SPLIT_GAIN, threshold=PIR_THRESHOLD,
                     soft_spread=PIR_SPREAD, evidence_reference=None, multiplicity=PIR_MULTIPLICITY,
                     expected_gain=PIR_EXPECTED_GAIN, shared_support=PIR_SHARED_SUPPORT,
                     count_switch=PIR_COUNT_SWITCH, count_threshold=1, count_soft=PIR_COUNT_SPREAD)
    return fusion, config
