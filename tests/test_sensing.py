"""Sensing models: what each sensor kind reports for a target state."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bintrack.deployment_model import DiskSensor, LineSensor, MotionSensor, SectorSensor
from bintrack.sensing import (
    DiskModel,
    LineModel,
    MotionModel,
    SectorModel,
    detection_probability,
    draw_effective_radius,
    exponential_alpha,
    model_for,
)


def test_model_for_builds_each_kind():
    assert isinstance(model_for(DiskSensor(id="d", x=0, y=0, range=1)), DiskModel)
    assert isinstance(model_for(SectorSensor(id="s", x=0, y=0, range=1, sectors=4)), SectorModel)
    assert isinstance(model_for(MotionSensor(id="m", x=0, y=0, period=1)), MotionModel)
    assert isinstance(model_for(LineSensor(id="l", a=0.1, b=0.2)), LineModel)
    with pytest.raises(ValueError, match="no beam"):
        model_for(LineSensor(id="l", x=1, y=0))


def test_ideal_disk_reports_inside_range():
    model = model_for(DiskSensor(id="d", x=10, y=0, range=5))
    positions = np.array([[10, 0], [14.9, 0], [15.1, 0], [10, -4.99], [0, 0]])
    assert model.status(positions).tolist() == [1, 1, 0, 1, 0]
    assert model.detect_probability(positions).tolist() == [1, 1, 0, 1, 0]
    assert not model.imperfect


def test_detection_laws_of_paper_001():
    r_in, r_out = 36.0, 40.0
    d = np.array([0.0, 36.0, 37.0, 38.0, 39.9999, 40.0, 50.0])
    linear = detection_probability(d, r_in, r_out, "linear")
    assert linear.tolist() == pytest.approx([1, 1, 0.75, 0.5, 0.000025, 0, 0])
    alpha = exponential_alpha(r_in, r_out)
    assert alpha == pytest.approx(math.log(1e-4) / (r_in - r_out))
    assert math.exp(-alpha * (r_out - r_in)) == pytest.approx(1e-4)
    expo = detection_probability(d, r_in, r_out, "exponential")
    assert expo[:2].tolist() == [1, 1]
    assert expo[2] == pytest.approx(math.exp(-alpha))
    assert expo[-2:].tolist() == [0, 0]
    assert np.all(np.diff(expo) <= 0)
    with pytest.raises(ValueError):
        detection_probability(d, r_in, r_out, "cubic")


def test_imperfect_disk_model_from_sensor():
    model = model_for(DiskSensor(id="d", x=0, y=0, range=40, range_in=36, detection_law="exponential"))
    assert model.imperfect and model.range_in == 36 and model.law == "exponential"
    assert model.detect_probability([[0, 38]])[0] == pytest.approx(detection_probability(38, 36, 40, "exponential"))


@pytest.mark.parametrize("law", ["linear", "exponential"])
def test_effective_radius_has_the_detection_law_as_survival_function(law):
    rng = np.random.default_rng(5)
    radii = np.array([draw_effective_radius(rng, 36.0, 40.0, law) for _ in range(20000)])
    assert radii.min() >= 36.0 and radii.max() <= 40.0
    for d in (36.5, 37.0, 38.0, 39.0, 39.5):
        assert np.mean(radii > d) == pytest.approx(float(detection_probability(d, 36.0, 40.0, law)), abs=0.012)


def test_effective_radius_of_the_ideal_model_is_the_range():
    assert draw_effective_radius(np.random.default_rng(0), 40.0, 40.0, None) == 40.0


def test_sector_numbering_is_clockwise_from_offset():
    # 4 sectors, offset π/2: sector 0 is (0, π/2], 1 is (−π/2, 0], 2 is (−π, −π/2], 3 is (π/2, π]
    model = model_for(SectorSensor(id="s", x=1, y=1, range=10, sectors=4, offset=math.pi / 2))
    angles = [math.pi / 4, -math.pi / 4, -3 * math.pi / 4, 3 * math.pi / 4, math.pi / 2, 0.0, math.pi]
    positions = np.array([[1 + 5 * math.cos(a), 1 + 5 * math.sin(a)] for a in angles])
    assert model.sector_of(positions).tolist() == [0, 1, 2, 3, 0, 1, 3]
    assert model.status(positions).tolist() == [0, 1, 2, 3, 0, 1, 3]
    assert model.status(np.array([[1, 20]])).tolist() == [-1]
    assert model.boundary_angles().tolist() == pytest.approx([math.pi / 2, 0, 3 * math.pi / 2, math.pi])
    lo, hi = model.sector_interval(0)
    assert (lo, hi) == pytest.approx((0.0, math.pi / 2))
    lo, hi = model.sector_interval(3)
    assert (lo, hi) == pytest.approx((math.pi / 2, math.pi))


def test_sector_of_every_direction_is_in_range():
    model = SectorModel(0, 0, 1, 1, None, sectors=7, offset=-2.5)
    a = np.linspace(-10, 10, 2001)
    k = model.sector_of(np.stack([np.cos(a), np.sin(a)], axis=1))
    assert k.min() == 0 and k.max() == 6
    for angle, sector in zip(a, k):
        lo, hi = model.sector_interval(int(sector))
        assert (angle - lo) % (2 * math.pi) <= hi - lo + 1e-12


def test_motion_sign_closer_and_farther():
    model = model_for(MotionSensor(id="m", x=10, y=0, period=1))
    positions = np.array([[0, 0], [0, 0], [20, 0], [0, 0]])
    velocities = np.array([[1, 0], [-1, 0], [1, 0], [0, 1]])
    assert model.status(positions, velocities).tolist() == [1, -1, -1, -1]


def test_line_beam_side_and_crossing():
    model = model_for(LineSensor(id="l", a=0.1, b=0.05))  # x/10 + y/20 = 1
    assert model.side([[10, 0], [0, 20], [0, 0]]).tolist() == pytest.approx([0, 0, -1])
    assert model.crossed([[0, 0], [0, 0]], [[20, 20], [1, 1]]).tolist() == [True, False]
