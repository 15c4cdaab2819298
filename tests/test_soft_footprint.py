"""Real PIR in the multi-target tracker: reports placed under Gaussian footprints
(``bintrack.trackers.multi.soft_footprint``), switched on only for deployments whose sensors carry
the fitted ``hold`` field (``pir_settings``)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from bintrack.deployment_model import Deployment, DiskSensor, Region
from bintrack.errors import TrackerConfigError
from bintrack.trackers.multi.fusion import GridFusion
from bintrack.trackers.multi.fusion_config import FusionConfig
from bintrack.trackers.multi.mcmcda_config import MCMCDAConfig
from bintrack.trackers.multi.pir_settings import pir_settings
from bintrack.trackers.multi.soft_footprint import SoftFootprint


def _line() -> SoftFootprint:
    """Four sensors on a line 1 m apart, σ 0.6 m, pd 0.7, pfa 0.01."""
    n = 4
    return SoftFootprint(np.array([(float(i), 0.0) for i in range(n)]), np.full(n, 0.6), np.full(n, 0.7), np.full(n, 0.01))


def _mean(soft: SoftFootprint, detecting, others=()) -> float:
    xs = np.arange(-1.0, 4.0, 0.05)
    cells = np.array([(x, 0.0) for x in xs])
    log_l = soft.log_likelihood(cells, np.array(detecting), np.array(others, dtype=float).reshape(-1, 2), reach=3.0)
    w = np.exp(log_l - log_l.max())
    return float((w * xs).sum() / w.sum())


def test_a_report_lies_where_the_pattern_of_firings_and_misses_puts_it():
    soft = _line()
    assert _mean(soft, [0, 1, 1, 0]) == pytest.approx(1.5, abs=1e-3)  # symmetric
    assert _mean(soft, [0, 1, 0, 0]) == pytest.approx(1.0, abs=0.15)  # under the one that fired
    # a silent neighbour pushes the person away from it: sensor 0 fires, 1 is silent
    assert _mean(soft, [1, 0, 0, 0]) < 0.0


def test_a_sensor_explained_by_another_target_pulls_less():
    soft = _line()
    alone = _mean(soft, [0, 1, 1, 0])
    beside = _mean(soft, [0, 1, 1, 0], others=[(2.0, 0.0)])  # a second person under sensor 2
    assert beside < alone - 0.1


def _room(hold) -> Deployment:
    sensors = [DiskSensor(id=f"s{i}", x=float(i), y=1.0, range=1.2, pd=0.7, pfa=0.01, period=0.5, hold=hold)
               for i in range(5)]
    return Deployment(name="room", units="m", region=Region(xmin=-1, ymin=0, xmax=5, ymax=2), sensors=sensors)


def test_only_a_fitted_deployment_gets_the_real_pir_settings():
    fusion, config = pir_settings(_room(hold=None), FusionConfig(), MCMCDAConfig())
    assert (fusion, config) == (FusionConfig(), MCMCDAConfig())
    assert GridFusion(_room(hold=None), fusion).soft is None
    fusion, config = pir_settings(_room(hold=0.0), FusionConfig(), MCMCDAConfig())
    assert fusion.soft_spread == 0.5 and fusion.threshold == 2
    assert fusion.evidence_reference is None and config.exit_depth is None  # chosen outdoors, not tried here
    assert config.max_misses == 5 and config.coast == 2  # a person unreported for a scan is still shown
    assert config.process_noise == 0.035  # people in a room turn more than walkers crossing a field
    assert config.smooth_noise == 0.1  # --lag's smoother lets them turn more freely still
    assert (config.entry_depth, config.entry_gain) == (1.0, 4.0)  # people coming in are shown from one report
    assert GridFusion(_room(hold=0.0), fusion).soft.spread == pytest.approx(np.full(5, 0.6))


def test_a_bad_spread_is_refused():
    with pytest.raises(TrackerConfigError, match="soft_spread"):
        GridFusion(_room(hold=0.0), FusionConfig(soft_spread=0.0))


def test_soft_gains_count_one_person_under_a_soft_footprint_once():
    """Sensors 0-3 on a line 1 m apart: 1 and 2 fire. One person between them explains both;
    given the first, a second person under sensor 2 adds less than the bar of a new target
    (2 nats), while alone a person there would clear it."""
    soft = _line()
    y = np.array([0, 1, 1, 0])
    alone = soft.gains(np.array([(1.5, 0.0)]), y)
    assert alone[0] > 2.0
    pair = soft.gains(np.array([(1.5, 0.0), (2.0, 0.0)]), y)
    assert pair[1] < 2.0 < soft.gains(np.array([(2.0, 0.0)]), y)[0]
    # two people far apart, each under a firing sensor: each is needed
    far = SoftFootprint(np.array([(0.0, 0.0), (5.0, 0.0)]), np.full(2, 0.6), np.full(2, 0.7), np.full(2, 0.01))
    assert (far.gains(np.array([(0.0, 0.0), (5.0, 0.0)]), np.array([1, 1])) > 2.0).all()


def test_a_bad_soft_count_is_refused():
    with pytest.raises(TrackerConfigError, match="soft_count"):
        GridFusion(_room(hold=0.0), FusionConfig(soft_count=-1.0))


def test_soft_count_drops_a_target_the_soft_footprints_do_not_need():
    """Six sensors 1 m apart, 1, 2 and 4 fire: the disks (1.2 m) need two people; Gaussian
    footprints of σ = R (soft_count 1) explain sensor 4 by the person near 2, and keep one."""
    sensors = [DiskSensor(id=f"s{i}", x=float(i), y=1.0, range=1.2, pd=0.7, pfa=0.01, period=0.5, hold=0.0)
               for i in range(6)]
    room = Deployment(name="room", units="m", region=Region(xmin=-1, ymin=0, xmax=6, ymax=2), sensors=sensors)
    fusion, _ = pir_settings(room, FusionConfig(), MCMCDAConfig())
    pattern = np.array([0, 1, 1, 0, 1, 0])
    assert len(GridFusion(room, fusion).reports(pattern)) == 2
    assert len(GridFusion(room, replace(fusion, soft_count=1.0)).reports(pattern)) == 1
