"""Real sensors: import of a sample matrix + sensor table + CVML truth, CLEAR MOT scoring, the
calibration of PIR sensors from their detections, the simulator's PIR model, and the real
ceiling-PIR recording of Milan et al. end to end (skipped when ../shared/realdata is missing)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from bintrack.calibration.pir_calibration import _pairs_of, calibrate, lens_fraction
from bintrack.calibration.sample_series import sample_series
from bintrack.cli import main as cli
from bintrack.evaluation.clear_mot import Frame, clear_mot
from bintrack.formats import open_dataset, read_deployment, write_dataset
from bintrack.deployment_model import Deployment, DiskSensor, Region
from bintrack.sim.engine import simulate_scenario
from bintrack.sim.recorded_paths import recording_scenario
from bintrack.formats import TruthRow

from support import REPO

REAL = REPO.parent / "shared" / "realdata" / "irtracking"
needs_real = pytest.mark.skipif(not (REAL / "r1-easy.txt").exists(), reason="../shared/realdata/irtracking is missing")

CVML = """<?xml version="1.0" encoding="utf-8"?>
<dataset name="x">
 <frame number="1"><objectlist/></frame>
 <frame number="2"><objectlist><object id="1"><box h="28" w="28" xc="40" yc="80"/></object></objectlist></frame>
 <frame number="3"><objectlist><object id="1"><box h="28" w="28" xc="44" yc="80"/></object>
   <object id="2"><box h="28" w="28" xc="10" yc="10"/></object></objectlist></frame>
</dataset>
"""


def small_recording(tmp: Path) -> Path:
    (tmp / "m.txt").write_text("start 2013-9-19\n0 0 3 9\n0 5 5 9\n7 0 0 9\n")
    (tmp / "s.csv").write_text("column,x_mm,y_mm\n1,1000,2000\n2,1500,2000\n3,2000,2000\n")
    (tmp / "gt.xml").write_text(CVML)
    return tmp


def run_import(tmp: Path, *extra: str) -> int:
    return cli.main(["import", str(tmp / "m.txt"), "--sensors", str(tmp / "s.csv"), "--out", str(tmp / "ds"),
                     "--period", "0.5", "--header-lines", "1", "--range", "0.7", *extra])


def test_import_writes_a_dataset_in_metres(tmp_path):
    src = small_recording(tmp_path)
    assert run_import(src, "--truth", str(src / "gt.xml"), "--truth-scale", "25", "--truth-units", "mm",
                      "--columns", "1-3") == 0
    ds = open_dataset(src / "ds")
    assert [(s.id, s.x, s.y, s.range, s.period) for s in ds.deployment.sensors] == [
        ("1", 1.0, 2.0, 0.7, 0.5), ("2", 1.5, 2.0, 0.7, 0.5), ("3", 2.0, 2.0, 0.7, 0.5)]
    assert [tuple(e) for e in ds.events()] == [(0.0, "3", 1), (0.5, "2", 1), (1.0, "1", 1), (1.0, "2", 0), (1.0, "3", 0)]
    # frame N at (N - 1)·period; 25 mm per CVML unit
    assert [tuple(r) for r in ds.truth()] == [(0.5, "1", 1.0, 2.0), (1.0, "1", 1.1, 2.0), (1.0, "2", 0.25, 0.25)]


@pytest.mark.parametrize("extra, words", [
    (("--header-lines", "0"), "m.txt:1: sample: not a number"),
    (("--columns", "1-5"), "no sensor reads column 4"),
    (("--truth", "missing.xml"), "missing.xml"),
])
def test_import_rejects_bad_input_with_one_line(tmp_path, capsys, extra, words):
    src = small_recording(tmp_path)
    args = ["import", str(src / "m.txt"), "--sensors", str(src / "s.csv"), "--out", str(src / "ds"), "--period", "0.5",
            "--range", "0.7", *extra]
    if "--header-lines" not in extra:
        args += ["--header-lines", "1"]
    assert cli.main(args) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and "\n" not in err and "Traceback" not in err


def test_import_rejects_a_table_without_units(tmp_path, capsys):
    src = small_recording(tmp_path)
    (src / "s.csv").write_text("column,x,y\n1,1,2\n")
    assert run_import(src) == 2
    assert "no unit" in capsys.readouterr().err


def test_a_recording_too_short_for_intervals_is_calibrated_with_a_warning(tmp_path, capsys):
    """Three samples: the fit runs (it used to fail inside numpy), says it has no intervals
    rather than printing ones of width 0, and writes the fitted deployment."""
    src = small_recording(tmp_path)
    assert run_import(src) == 0
    capsys.readouterr()
    assert cli.main(["calibrate", str(src / "ds"), "--out", str(src / "fit")]) == 0
    out, err = capsys.readouterr()
    assert "only 3 samples: too few for intervals" in err and "Traceback" not in err
    pooled_radius = out.splitlines()[2].split("m)")[1].split()
    assert not pooled_radius[1].startswith("[")  # its value, then the sensors' median: no interval between
    assert all(s.pd is not None for s in open_dataset(src / "fit").deployment.sensors)


def test_old_deployments_load_and_new_fields_are_optional():
    old = read_deployment(REPO / "datasets" / "darpa-grid-1" / "deployment.json")
    assert all(s.hold is None and s.still is None for s in old.sensors if isinstance(s, DiskSensor))
    fitted = DiskSensor(id="a", x=0, y=0, range=1.2, pd=0.6, pfa=0.001, period=0.5, hold=0.5, still=0.3)
    assert fitted.hold == 0.5 and fitted.still == 0.3


def _frame(t, targets, txy, tracks, kxy):
    return Frame(t, tuple(targets), np.array(txy, float).reshape(-1, 2), tuple(tracks), np.array(kxy, float).reshape(-1, 2))


def test_clear_mot_counts_misses_false_positives_and_switches():
    frames = [
        _frame(0, ["a", "b"], [(0, 0), (5, 0)], [1, 2], [(0.5, 0), (5, 0)]),
        _frame(1, ["a", "b"], [(0, 0), (5, 0)], [1], [(0.2, 0)]),          # b missed
        _frame(2, ["a", "b"], [(0, 0), (5, 0)], [3, 2, 9], [(0, 0), (5, 1), (20, 20)]),  # a switches 1 -> 3; 9 false
    ]
    m = clear_mot(frames, 1.5)
    assert (m.ground_truth, m.matches, m.misses, m.false_positives, m.switches) == (6, 5, 1, 1, 1)
    assert m.mota == pytest.approx(1 - 3 / 6)
    assert m.motp_distance == pytest.approx((0.5 + 0 + 0.2 + 0 + 1) / 5)
    assert 0 < m.idf1 < 1


def test_greedy_and_hungarian_matching_differ_where_they_should():
    # greedy takes the closest pair (a-1 at 0.9) and leaves b with nothing within 1 m;
    # the optimal assignment pairs both
    frames = [_frame(0, ["a", "b"], [(0, 0), (1.8, 0)], [1, 2], [(0.9, 0), (-0.9, 0)])]
    assert clear_mot(frames, 1.0, "greedy").matches == 1
    assert clear_mot(frames, 1.0, "hungarian").matches == 2


def test_lens_fraction_is_one_at_zero_and_zero_at_two_radii():
    assert lens_fraction(0.0, 1.0) == pytest.approx(1.0)
    assert lens_fraction(2.0, 1.0) == pytest.approx(0.0)
    assert 0 < lens_fraction(1.0, 1.0) < 1


def test_each_sensors_pairs_are_those_its_mask_selects():
    """The radius fit's pairs of each sensor, found for all sensors at once, are the ones (and in
    the order) that the mask ``(ii == i) | (jj == i)`` of each sensor selects."""
    rng = np.random.default_rng(5)
    n = 30
    ii, jj = rng.integers(0, n, 400), rng.integers(0, n, 400)
    keep = ii != jj
    ii, jj = ii[keep], jj[keep]
    pairs = _pairs_of(ii, jj, n)
    assert len(pairs) == n
    for i in range(n):
        assert pairs[i].tolist() == np.flatnonzero((ii == i) | (jj == i)).tolist()
    assert [p.size for p in _pairs_of(np.array([], int), np.array([], int), 3)] == [0, 0, 0]


def test_calibration_reports_its_progress_and_is_unchanged_by_it(tmp_path, capsys):
    """``progress(done, total)`` after each bootstrap fit; ``calibrate --progress`` shows it on stderr."""
    deployment = _room()
    events = simulate_scenario(recording_scenario(deployment, _walkers(2, duration=40.0), (0.0, 40.0)), seed=1).events
    series = sample_series(deployment, events)
    seen = []
    with_progress = calibrate(series, stated_range=0.7, boot=5, progress=lambda done, total: seen.append((done, total)))
    assert seen == [(k, 5) for k in range(1, 6)]
    assert with_progress == calibrate(series, stated_range=0.7, boot=5)
    write_dataset(tmp_path / "room", deployment, events)
    args = ["calibrate", str(tmp_path / "room"), "--boot", "5", "--progress", "--out"]
    assert cli.main([*args, str(tmp_path / "fit")]) == 0
    err = capsys.readouterr().err
    assert "calibrate: bootstrap: 5/5 (100 %)" in err
    assert cli.main([*args[:-2], "--no-progress", "--out", str(tmp_path / "quiet")]) == 0
    assert "bootstrap" not in capsys.readouterr().err
    assert (tmp_path / "fit" / "deployment.json").read_bytes() == (tmp_path / "quiet" / "deployment.json").read_bytes()


def _room(pd=0.6, pfa=0.002, hold=None, radius=1.3) -> Deployment:
    xs, ys = np.meshgrid(np.arange(0.5, 8, 1.3), np.arange(0.5, 14, 1.3))
    sensors = [DiskSensor(id=f"s{i}", x=float(x), y=float(y), range=radius, pd=pd, pfa=pfa, period=0.5, hold=hold)
               for i, (x, y) in enumerate(zip(xs.ravel(), ys.ravel()))]
    return Deployment(name="room", units="m", region=Region(xmin=0, ymin=0, xmax=8.6, ymax=14), sensors=sensors)


def _walkers(seed: int, people: int = 4, duration: float = 240.0) -> list[TruthRow]:
    rng = np.random.default_rng(seed)
    rows = []
    for k in range(people):
        p = rng.uniform((0.5, 0.5), (8, 13.5))
        t = 0.0
        while t < duration:
            q = rng.uniform((0.5, 0.5), (8, 13.5))
            rows.append(TruthRow(t, str(k), float(p[0]), float(p[1])))
            t += float(np.hypot(*(q - p))) / 1.0
            p = q
        rows.append(TruthRow(t, str(k), float(p[0]), float(p[1])))
    return rows


@pytest.mark.slow
@pytest.mark.parametrize("hold", (0.0, 0.5))
def test_calibration_recovers_a_simulated_pir_room(hold):
    """Simulated with known radius 1.3 m, pd 0.6, pfa 0.002 and hold: the detections alone
    give radius and pd within 25 % (median over sensors), the hold exactly."""
    truth = _walkers(1)
    deployment = _room(hold=hold)
    result = simulate_scenario(recording_scenario(deployment, truth, (0.0, 240.0)), seed=3)
    fit = calibrate(sample_series(deployment, result.events), stated_range=0.7, boot=0)
    med = {k: np.median([getattr(f, k).value for f in fit.sensors]) for k in ("range", "pd", "pfa", "hold")}
    assert med["hold"] == hold
    assert med["range"] == pytest.approx(1.3, rel=0.25)
    assert med["pd"] == pytest.approx(0.6, rel=0.25)
    assert med["pfa"] < 0.01


def _field(pfa: float) -> tuple[Deployment, list]:
    """8 × 8 sensors 2.5 m apart whose footprints reach 4 m (pd 0.8), as in a grid of outdoor
    PIR, and four people walking across the 20 m field for 4 minutes: the deployment and events."""
    xs, ys = np.meshgrid(np.arange(0.5, 20, 2.5), np.arange(0.5, 20, 2.5))
    sensors = [DiskSensor(id=f"s{i}", x=float(x), y=float(y), range=4.0, pd=0.8, pfa=pfa, period=0.5)
               for i, (x, y) in enumerate(zip(xs.ravel(), ys.ravel()))]
    field = Deployment(name="field", units="m", region=Region(xmin=0, ymin=0, xmax=20, ymax=20), sensors=sensors)
    rng = np.random.default_rng(1)
    truth = []
    for k in range(4):
        p, t = rng.uniform(1, 19, 2), 0.0
        while t < 240.0:
            q = rng.uniform(1, 19, 2)
            truth.append(TruthRow(t, str(k), float(p[0]), float(p[1])))
            t, p = t + float(np.hypot(*(q - p))), q
        truth.append(TruthRow(t, str(k), float(p[0]), float(p[1])))
    return field, simulate_scenario(recording_scenario(field, truth, (0.0, 240.0)), seed=3).events


def test_calibration_finds_a_footprint_wider_than_the_sensors_spacing():
    """The pooled fit's first local search from 8 m stopped at 9 m; started again from the best
    radius of a grid it finds 4 m, and the sensors' median within 25 %."""
    field, events = _field(pfa=0.002)
    fit = calibrate(sample_series(field, events), stated_range=4.0, boot=0)
    assert fit.pooled.range.value == pytest.approx(4.0, rel=0.25)
    assert np.median([f.range.value for f in fit.sensors]) == pytest.approx(4.0, rel=0.25)


def test_sensors_that_never_fire_do_not_shrink_the_footprints():
    """Thirteen of the 64 sensors dead: as neighbours they were expected to fire with the pooled
    pd and never did, which took the pooled radius from 4.1 to 3.3 m. Pairs need both to fire."""
    field, events = _field(pfa=0.002)
    dead = {f"s{i}" for i in range(0, 64, 5)}
    whole = calibrate(sample_series(field, events), stated_range=4.0, boot=0)
    some_dead = calibrate(sample_series(field, [e for e in events if e.sensor not in dead]), stated_range=4.0, boot=0)
    assert some_dead.pooled.range.value == pytest.approx(whole.pooled.range.value, rel=0.02)


def test_calibration_measures_frequent_false_alarms():
    """At pfa 0.05 per sample no sample is quiet within 4 stated ranges (16 m) of a sensor, and
    pfa came out at its floor, 1e-4; within a closer neighbourhood it is found."""
    field, events = _field(pfa=0.05)
    fit = calibrate(sample_series(field, events), stated_range=4.0, boot=0)
    assert fit.pooled.pfa.value == pytest.approx(0.05, rel=0.25)
    assert np.median([f.pfa.value for f in fit.sensors]) == pytest.approx(0.05, rel=0.25)


def test_pir_hold_keeps_the_output_on():
    truth = [TruthRow(0.0, "p", 0.0, 0.0), TruthRow(0.5, "p", 0.0, 0.0)]
    sensor = DiskSensor(id="a", x=0, y=0, range=1.0, pd=1.0, pfa=0.0, period=0.5, hold=1.0)
    deployment = Deployment(name="one", units="m", region=Region(xmin=-2, ymin=-2, xmax=2, ymax=2), sensors=[sensor])
    events = simulate_scenario(recording_scenario(deployment, truth, (0.0, 3.0)), seed=0).events
    # on while the person is there (0, 0.5 s) and at the samples within 1 s after the last trigger: off at 2 s
    assert [(e.t, e.value) for e in events] == [(0.0, 1), (2.0, 0)]


def test_pir_still_person_fades():
    truth = [TruthRow(0.0, "p", 0.0, 0.0), TruthRow(100.0, "p", 0.0, 0.0)]  # standing still for 100 s
    sensor = DiskSensor(id="a", x=0, y=0, range=1.0, pd=1.0, pfa=0.0, period=0.5, hold=0.0, still=0.0)
    deployment = Deployment(name="one", units="m", region=Region(xmin=-2, ymin=-2, xmax=2, ymax=2), sensors=[sensor])
    assert simulate_scenario(recording_scenario(deployment, truth, (0.0, 100.0)), seed=0).events == []


# --------------------------------------------------------------------------- the real recording


def import_real(name: str, out: Path, *extra: str) -> Path:
    assert cli.main(["import", str(REAL / f"{name}.txt"), "--sensors", str(REAL / "sensors.csv"), "--out", str(out),
                     "--period", "0.5", "--columns", "1-43", "--header-lines", "1", "--range", "0.7",
                     "--region", "0,0,8.6,14", "--truth", str(REAL / f"{name}_gt.xml"), "--truth-scale", "25",
                     "--truth-units", "mm", *extra]) == 0
    return out


def calibrated_real(name: str, tmp: Path, boot: str = "0", *extra: str) -> Path:
    imported = import_real(name, tmp / "imported", *extra)
    blind = tmp / "blind"
    blind.mkdir()
    for f in ("deployment.json", "events.csv"):
        shutil.copyfile(imported / f, blind / f)
    assert cli.main(["calibrate", str(blind), "--out", str(tmp / "fitted"), "--boot", boot]) == 0
    assert not (tmp / "fitted" / "truth.csv").exists()
    shutil.copyfile(imported / "truth.csv", tmp / "fitted" / "truth.csv")
    return tmp / "fitted"


@needs_real
def test_the_real_recording_imports(tmp_path):
    ds = open_dataset(import_real("r1-medium", tmp_path / "m"))
    assert len(ds.deployment.sensors) == 43
    assert len({r.target for r in ds.truth()}) == 6
    assert max(e.t for e in ds.events()) <= 79.5


@needs_real
@pytest.mark.slow
def test_calibration_agrees_with_the_truth_on_the_real_recording(tmp_path):
    """Calibrated from the detections alone vs fitted to the truth: radius and pd within 25 %
    (median over sensors of the relative difference), on both sequences."""
    for name in ("r1-easy", "r1-medium"):
        fitted = calibrated_real(name, tmp_path / name)
        assert cli.main(["calibrate", str(tmp_path / name / "imported"), "--out", str(tmp_path / name / "sup"),
                         "--supervised"]) == 0
        a = {s["id"]: s for s in json.loads((fitted / "deployment.json").read_text())["sensors"]}
        b = {s["id"]: s for s in json.loads((tmp_path / name / "sup" / "deployment.json").read_text())["sensors"]}
        for key in ("range", "pd"):
            rel = np.median([abs(a[i][key] - b[i][key]) / b[i][key] for i in a])
            assert rel <= 0.25, (name, key, rel)


@needs_real
@pytest.mark.slow
def test_mcmcda_tracks_the_calibrated_real_recording(tmp_path, capsys):
    """r1-medium, calibrated without truth, mcmcda at its defaults (seed 0): better than the
    authors' offline tracker's MOTA (52.9 %) and far better than the stated footprint alone
    (count error 4.1, GOSPA 2.79 m)."""
    fitted = calibrated_real("r1-medium", tmp_path)
    assert cli.main(["track", str(fitted), "--tracker", "mcmcda", "--out", str(tmp_path / "t.csv"), "--no-progress"]) == 0
    capsys.readouterr()
    assert cli.main(["eval", str(fitted), str(tmp_path / "t.csv"), "--gospa-c", "2", "--area", "0,0,8,14", "--json"]) == 0
    scores = json.loads(capsys.readouterr().out)
    assert scores["mota"] > 0.529
    assert scores["target_count_error_mean"] < 1.0
    assert scores["gospa_mean"] < 2.3


@needs_real
@pytest.mark.slow
def test_live_equals_offline_on_the_real_recording_in_real_time(tmp_path):
    from test_live import live_and_offline

    live_and_offline(calibrated_real("r1-medium", tmp_path), "mcmcda", tmp_path, speed="1", exports=("tracks",))


@needs_real
@pytest.mark.slow
def test_live_equals_offline_with_the_rooms_floor_plan(tmp_path):
    """The room's floor plan reaches the live base station inside the deployment: live equals offline."""
    from test_live import live_and_offline

    plan = REPO / "benchmarks" / "irtracking_floor_plan.json"
    fitted = calibrated_real("r1-easy", tmp_path, "0", "--floor-plan", str(plan))
    assert read_deployment(fitted / "deployment.json").floor_plan is not None
    live_and_offline(fitted, "mcmcda", tmp_path, speed="4", exports=("tracks",))
