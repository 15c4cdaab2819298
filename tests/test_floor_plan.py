"""A deployment's floor plan (``floor_plan`` in deployment.json, ``bintrack import --floor-plan``):
no target is placed inside an obstacle, and with real PIR people are born near the named doors."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from bintrack.cli import main as cli
from bintrack.deployment_model import Deployment, DiskSensor, FloorPlan, Region
from bintrack.errors import TrackerConfigError
from bintrack.floor_plan import FloorShape
from bintrack.formats import read_deployment, write_deployment
from bintrack.trackers.multi.fusion import GridFusion
from bintrack.trackers.multi.fusion_config import FusionConfig
from bintrack.trackers.multi.mcmcda import OnlineMCMCDA
from bintrack.trackers.multi.mcmcda_config import MCMCDAConfig
from bintrack.trackers.multi.mcmcda_window import WindowReport
from bintrack.trackers.multi.pir_settings import pir_settings

from test_real_sensors import run_import, small_recording

PLAN = {"obstacles": [{"xmin": 1.3, "ymin": 0.0, "xmax": 3.0, "ymax": 2.0},
                      {"polygon": [[4.5, 0.0], [5.0, 0.0], [5.0, 0.5]]}],
        "doors": [[-1.0, 1.0]]}


def _room(plan: dict | None = None) -> Deployment:
    """Five fitted PIR sensors on a line 1 m apart, 1.2 m footprints, pd 0.7, pfa 0.01."""
    sensors = [DiskSensor(id=f"s{i}", x=float(i), y=1.0, range=1.2, pd=0.7, pfa=0.01, period=0.5, hold=0.0)
               for i in range(5)]
    return Deployment(name="room", units="m", region=Region(xmin=-1, ymin=0, xmax=5, ymax=2), sensors=sensors,
                      floor_plan=None if plan is None else FloorPlan.model_validate(plan))


def test_the_floor_plan_is_optional_and_round_trips(tmp_path):
    assert _room().floor_plan is None
    write_deployment(tmp_path / "deployment.json", _room(PLAN))
    back = read_deployment(tmp_path / "deployment.json")
    assert back == _room(PLAN)
    write_deployment(tmp_path / "old.json", _room())
    assert "floor_plan" not in (tmp_path / "old.json").read_text()


def test_the_plan_crosses_the_bus_to_the_live_services():
    """The ``deployment`` queryable's payload carries the plan, so a live base station builds the
    same fusion as ``bintrack track``."""
    from bintrack.message_codec import decode, encode

    back = decode(Deployment, encode(_room(PLAN)))
    assert back == _room(PLAN)
    fusion, _ = pir_settings(back, FusionConfig(), MCMCDAConfig())
    assert GridFusion(back, fusion).free.tolist() == GridFusion(_room(PLAN), fusion).free.tolist()


def test_floor_shape_tells_free_points():
    shape = FloorShape(FloorPlan.model_validate(PLAN))
    assert shape.free(np.array([(1.0, 1.0), (2.0, 1.0), (3.0, 1.0), (4.9, 0.1), (4.6, 0.4)])).tolist() == [
        True, False, True, False, True]  # an obstacle's border is free
    assert FloorShape(FloorPlan()).free(np.zeros((2, 2))).all()


def test_no_report_is_placed_inside_an_obstacle():
    """Sensors 1 and 2 fire: a person between them, at x = 1.5 without a plan; with the floor
    between 1.3 and 3 m taken by a table, the report moves out of it, towards sensor 1. The
    targets are counted as before, on every cell."""
    fusion, _ = pir_settings(_room(), FusionConfig(), MCMCDAConfig())
    pattern = np.array([0, 1, 1, 0, 0])
    [open_floor] = GridFusion(_room(), fusion).reports(pattern)
    assert open_floor.x == pytest.approx(1.5, abs=0.05)
    grid = GridFusion(_room(PLAN), fusion)
    assert grid.free.tolist() == FloorShape(FloorPlan.model_validate(PLAN)).free(grid.cells).tolist()
    assert 0 < grid.free.sum() < len(grid.free) and GridFusion(_room(), fusion).free is None
    [planned] = grid.reports(pattern)
    assert planned.x <= 1.3
    assert planned.weight == open_floor.weight  # the same evidence: only the place moved
    [disk] = GridFusion(_room(PLAN), replace(fusion, soft_spread=None)).reports(pattern)  # the disks' report too
    assert disk.x <= 1.3


def test_a_target_wholly_inside_an_obstacle_is_still_reported():
    fusion, _ = pir_settings(_room(), FusionConfig(), MCMCDAConfig())
    everywhere = {"obstacles": [{"xmin": -1, "ymin": 0, "xmax": 5, "ymax": 2}]}
    [report] = GridFusion(_room(everywhere), fusion).reports(np.array([0, 1, 1, 0, 0]))
    assert report.x == pytest.approx(1.5, abs=0.05)


def test_people_are_born_near_the_doors():
    """With real PIR, λ_b is ten times lower farther than 1.5 m from a door; without doors in
    the plan, from the walls."""
    _, config = pir_settings(_room(PLAN), FusionConfig(), MCMCDAConfig())
    assert config.birth_doors == ((-1.0, 1.0),)
    chain = OnlineMCMCDA(config)
    near, far = (WindowReport(0, 0.0, x, 1.0, 0.1, 0.1) for x in (0.0, 2.5))
    assert chain._log_birth(far) == pytest.approx(chain._log_birth(near) + np.log(0.1))
    _, walls = pir_settings(_room(), FusionConfig(), MCMCDAConfig())
    assert walls.birth_doors is None
    on_the_walls = OnlineMCMCDA(walls)
    assert on_the_walls._log_birth(far) == on_the_walls._log_birth(near)  # both within 1.5 m of a wall


def test_a_crossed_obstacle_is_refused():
    bowtie = {"obstacles": [{"polygon": [[0, 0], [1, 1], [1, 0], [0, 1]]}]}
    with pytest.raises(TrackerConfigError, match="obstacle 1's polygon crosses itself"):
        GridFusion(_room(bowtie), FusionConfig())


def test_import_refuses_a_crossed_obstacle_with_one_line(tmp_path, capsys):
    src = small_recording(tmp_path)
    (src / "plan.json").write_text(json.dumps({"obstacles": [{"polygon": [[1, 1.5], [2, 2.5], [2, 1.5], [1, 2.5]]}]}))
    assert run_import(src, "--columns", "1-3", "--floor-plan", str(src / "plan.json")) == 2
    err = capsys.readouterr().err.strip()
    assert "plan.json: obstacles: floor plan: obstacle 1's polygon crosses itself" in err and "\n" not in err


def test_import_takes_a_floor_plan(tmp_path):
    src = small_recording(tmp_path)
    (src / "plan.json").write_text(json.dumps({"obstacles": [{"xmin": 1.1, "ymin": 1.5, "xmax": 1.4, "ymax": 2.5}],
                                               "doors": [[0.5, 2.0]]}))
    assert run_import(src, "--columns", "1-3", "--floor-plan", str(src / "plan.json")) == 0
    plan = read_deployment(src / "ds" / "deployment.json").floor_plan
    assert plan.doors == [(0.5, 2.0)] and plan.obstacles[0].vertices()[0] == (1.1, 1.5)


@pytest.mark.parametrize("text, words", [
    ("{", "plan.json:1: json:"),
    ("[]", "expected a JSON object"),
    ('{"obstacles": [{"polygon": [[0, 0], [1, 1]]}]}', "obstacles[0]: area: a polygon needs at least 3 vertices"),
    ('{"obstacles": [{"xmin": 2, "ymin": 0, "xmax": 1, "ymax": 1}]}', "area needs xmin < xmax"),
    ('{"doors": [[1, 2, 3]]}', "doors[0]: Tuple should have at most 2 items"),
    ('{"doors": [[50, 2]]}', "door (50, 2) lies outside the region"),
])
def test_a_bad_floor_plan_is_refused_with_one_line(tmp_path, capsys, text, words):
    src = small_recording(tmp_path)
    (src / "plan.json").write_text(text)
    assert run_import(src, "--columns", "1-3", "--floor-plan", str(src / "plan.json")) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and "\n" not in err and "Traceback" not in err
    assert not (src / "ds").exists()


def test_the_plan_survives_calibration(tmp_path):
    """``bintrack calibrate`` writes the fitted deployment with the plan it was given."""
    from test_real_sensors import _room as pir_room, _walkers
    from bintrack.formats import write_dataset
    from bintrack.sim.engine import simulate_scenario
    from bintrack.sim.recorded_paths import recording_scenario

    room = pir_room().model_copy(update={"floor_plan": FloorPlan.model_validate(
        {"obstacles": [{"xmin": 3.0, "ymin": 6.0, "xmax": 4.0, "ymax": 8.0}], "doors": [[0.0, 7.0]]})})
    events = simulate_scenario(recording_scenario(room, _walkers(1, duration=120.0), (0.0, 120.0)), seed=1).events
    write_dataset(tmp_path / "in", room, events, None)
    assert cli.main(["calibrate", str(tmp_path / "in"), "--out", str(tmp_path / "out")]) == 0
    assert read_deployment(tmp_path / "out" / "deployment.json").floor_plan == room.floor_plan


def test_checkpoints_of_configs_before_doors_still_load():
    old = replace(MCMCDAConfig(), birth_doors=None)
    assert old.in_units(0.3048).birth_doors is None
    assert MCMCDAConfig(birth_doors=((3.048, 0.0),)).in_units(0.3048).birth_doors == (pytest.approx((10.0, 0.0)),)


def test_the_plot_draws_the_floor_plan(tmp_path, monkeypatch):
    """``bintrack eval --plot`` of a deployment with a floor plan draws its obstacles and doors."""
    from matplotlib.figure import Figure

    from bintrack.evaluation.plotting import plot_scene

    drawn = []
    save = Figure.savefig
    monkeypatch.setattr(Figure, "savefig", lambda fig, *a, **k: (drawn.append(fig), save(fig, *a, **k))[1])
    plot_scene(tmp_path / "scene.png", _room(PLAN))
    labels = drawn[0].axes[0].get_legend_handles_labels()[1]
    assert "obstacles" in labels and "doors" in labels
    plot_scene(tmp_path / "open.png", _room())
    assert not {"obstacles", "doors"} & set(drawn[1].axes[0].get_legend_handles_labels()[1])
