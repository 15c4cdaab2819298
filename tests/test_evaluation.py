"""``bintrack eval``: figures by kind of result, the table, --json, --plot and bad input."""

import json
import math

import numpy as np
import pytest

from bintrack.cli import main as cli
from bintrack.errors import CommandError
from bintrack.evaluation.eval_report import evaluate
from bintrack.formats import Event, ObjectRow, TrackRow, TruthRow, write_dataset, write_objects, write_tracks
from bintrack.deployment_model import Deployment

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def disk_deployment(n=5, sensing_range=10.0):
    return Deployment.model_validate({
        "name": "evalnet", "units": "m", "region": {"xmin": 0, "ymin": 0, "xmax": 100, "ymax": 40},
        "sensors": [{"id": f"n{i}", "kind": "disk", "x": 10 + 20 * i, "y": 20, "range": sensing_range}
                    for i in range(n)]})


def line_truth(target, t0, t1, start, end):
    return [TruthRow(t0 + (t1 - t0) * k / 10, target, start[0] + (end[0] - start[0]) * k / 10,
                     start[1] + (end[1] - start[1]) * k / 10) for k in range(11)]


@pytest.fixture
def single(tmp_path):
    """One target along y = 20 from x = 0 to 100 in 100 s; sensor n0 detects it."""
    events = [Event(0.0, "n0", 1), Event(20.0, "n0", 0)]
    folder = write_dataset(tmp_path / "single", disk_deployment(), events, line_truth("a", 0, 100, (0, 20), (100, 20)))
    tracks = tmp_path / "tracks.csv"
    # 1 m to the side of the truth, velocity 0.5 m/s off on half of the rows
    write_tracks(tracks, [TrackRow(t, 0, t, 21, 1.0, 0.5 if t % 20 else 0.0) for t in np.arange(0, 101, 10.0)])
    return folder, tracks


@pytest.fixture
def multi(tmp_path):
    truth = line_truth("a", 0, 10, (0, 10), (100, 10)) + line_truth("b", 0, 10, (0, 30), (100, 30))
    folder = write_dataset(tmp_path / "multi", disk_deployment(), [Event(1.0, "n1", 1)], truth)
    tracks = tmp_path / "tracks.csv"
    rows = []
    for t in range(11):
        rows.append(TrackRow(t, 1, 10 * t, 13))            # 3 m off a
        if t >= 5:
            rows.append(TrackRow(t, 2, 10 * t, 30))        # b found from t = 5 on
    write_tracks(tracks, rows)
    return folder, tracks


def line_deployment():
    return Deployment.model_validate({
        "name": "lasers", "units": "ft", "region": {"xmin": 0, "ymin": 0, "xmax": 16, "ymax": 8},
        "sensors": [{"id": "L1", "kind": "line", "a": 0.25, "b": 0.0},
                    {"id": "L2", "kind": "line", "a": 0.1, "b": 0.1},
                    {"id": "L3", "kind": "line"}]})


@pytest.fixture
def objects(tmp_path):
    truth = line_truth("p1", 0, 10, (0, 0), (16, 8)) + line_truth("p2", 20, 30, (0, 8), (16, 0))
    folder = write_dataset(tmp_path / "lasers", line_deployment(), [Event(2.5, "L1", 1), Event(22.0, "L2", 1)], truth)
    result = tmp_path / "objects.csv"
    write_objects(result, [ObjectRow(1, 1, 9, 3, 4, 16, 8, 1.6, 0.8), ObjectRow(2, 21, 29, 0, 5, 16, 1, 1.6, -0.8)])
    return folder, result


def run_json(capsys, *args):
    code = cli.main(["eval", *map(str, args), "--json"])
    out = capsys.readouterr().out
    assert code == 0
    return json.loads(out)


def test_single_target_figures(capsys, single):
    figures = run_json(capsys, *single)
    assert figures["mode"] == "single" and figures["kind"] == "tracks" and figures["units"] == "m"
    assert figures["rows"] == 11 and figures["rows_scored"] == 11
    assert figures["location_error_mean"] == pytest.approx(1)
    assert figures["sensing_range"] == 10
    assert figures["location_error_over_R_mean"] == pytest.approx(0.1)
    assert figures["trajectory_error"] == pytest.approx(1)
    assert figures["velocity_rows"] == 11
    assert figures["velocity_error_mean"] == pytest.approx(0.5 * 5 / 11)
    assert figures["velocity_error_max"] == pytest.approx(0.5)


def test_table_is_aligned_and_names_the_headline(capsys, single):
    assert cli.main(["eval", *map(str, single)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("dataset") and str(single[0]) in lines[0]
    ev = evaluate(*single)
    figure_lines = lines[2:]
    assert len(figure_lines) == len(ev.figures)
    value_ends = {len(line[: len(line) - len(f.unit)].rstrip()) for f, line in zip(ev.figures, figure_lines)}
    assert len(value_ends) == 1  # values right-aligned in one column
    assert any(line.startswith("location error / R, mean") and line.split()[-1] == "0.1" for line in figure_lines)
    assert ev.headline() == "location error / R, mean 0.1"
    assert ev.value("trajectory_error") == pytest.approx(1)


def test_multi_target_figures(capsys, multi):
    figures = run_json(capsys, *multi, "--gospa-c", "10")
    assert figures["mode"] == "multi"
    assert (figures["targets"], figures["tracks"], figures["scans"]) == (2, 2, 11)
    # t < 5: a 3 m off, b missed: 9 + 50; t >= 5: 9 + 0
    expected = (5 * math.sqrt(59) + 6 * 3) / 11
    assert figures["gospa_mean"] == pytest.approx(expected)
    assert figures["gospa_localisation_mean"] == pytest.approx(9)
    assert figures["gospa_missed_mean"] == pytest.approx(50 * 5 / 11)
    assert figures["gospa_false_mean"] == 0
    assert figures["missed_targets_mean"] == pytest.approx(5 / 11)
    assert figures["target_count_error_mean"] == pytest.approx(5 / 11)
    assert figures["target_count_correct"] == pytest.approx(6 / 11)
    assert figures["identity_switches"] == 0
    assert figures["location_error_median"] == pytest.approx(3)
    assert figures["gospa_c"] == 10


def test_a_smaller_cut_off_turns_far_estimates_into_missed_and_false(capsys, multi):
    figures = run_json(capsys, *multi, "--gospa-c", "2")
    assert figures["gospa_localisation_mean"] == 0  # track 1, 3 m off a, is no longer assigned
    assert figures["false_tracks_mean"] == pytest.approx(1)


def test_object_figures(capsys, objects):
    figures = run_json(capsys, *objects)
    assert figures["mode"] == "objects" and figures["units"] == "ft"
    assert (figures["objects"], figures["objects_matched"]) == (2, 2)
    assert figures["entry_error_mean"] == pytest.approx(4) and figures["entry_error_max"] == pytest.approx(5)
    assert figures["exit_error_mean"] == pytest.approx(0.5) and figures["exit_error_max"] == pytest.approx(1)
    assert evaluate(*objects).headline() == "entry point error, mean 4 ft; exit point error, mean 0.5 ft"


@pytest.mark.parametrize("case", ["single", "multi", "objects"])
def test_plot_writes_a_png(request, capsys, tmp_path, case):
    folder, result = request.getfixturevalue(case)
    png = tmp_path / "out" / f"{case}.png"
    png.parent.mkdir()
    assert cli.main(["eval", str(folder), str(result), "--plot", str(png)]) == 0
    assert f"plot written to {png}" in capsys.readouterr().out
    data = png.read_bytes()
    assert data.startswith(PNG_MAGIC) and len(data) > 5000
    assert list(png.parent.iterdir()) == [png]


def test_plot_into_a_missing_folder_is_one_line_and_exit_2(capsys, single, tmp_path):
    assert cli.main(["eval", *map(str, single), "--plot", str(tmp_path / "nowhere" / "p.png")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "cannot write plot" in err


def test_no_truth_is_a_command_error(capsys, tmp_path):
    folder = write_dataset(tmp_path / "blind", disk_deployment(), [Event(0.0, "n0", 1)])
    result = tmp_path / "tracks.csv"
    write_tracks(result, [TrackRow(0, 0, 1, 1)])
    assert cli.main(["eval", str(folder), str(result)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"bintrack eval: error: no truth.csv in {folder}: nothing to score against"
    with pytest.raises(CommandError):
        evaluate(folder, result)


@pytest.mark.parametrize(
    "text, line, field",
    [
        ("t,track,x,y,vx,vy\n0,0,1,2,,\n1,0,abc,2,,\n", 3, "x"),
        ("t,track,x,y,vx,vy\n0,0,1,2,,\n1,zero,1,2,,\n", 3, "track"),
        ("t,track,x,y,vx,vy\n0,0,1\n", 2, "y"),
        ("object,t_first,t_last,entry_x,entry_y,exit_x,exit_y,vx,vy\n1,0,1,0,0,1,1,1,nan\n", 2, "vy"),
        ("time,id,px,py\n0,0,1,2\n", 1, "header"),
        ("", 1, "header"),
        ("t,track,y\n0,0,1\n", 1, "x"),
    ],
)
def test_bad_result_files_give_one_line_naming_file_line_and_field(capsys, single, tmp_path, text, line, field):
    bad = tmp_path / "bad.csv"
    bad.write_text(text)
    assert cli.main(["eval", str(single[0]), str(bad)]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert captured.out == "" and "\n" not in err
    assert f"{bad}:{line}: {field}:" in err


def test_missing_result_and_bad_cut_off_exit_2(capsys, single, tmp_path):
    assert cli.main(["eval", str(single[0]), str(tmp_path / "none.csv")]) == 2
    assert "none.csv: file: not found" in capsys.readouterr().err
    assert cli.main(["eval", str(single[0]), str(tmp_path)]) == 2
    assert "file: is a folder" in capsys.readouterr().err
    with pytest.raises(SystemExit) as stop:
        cli.main(["eval", *map(str, single), "--gospa-c", "-1"])
    assert stop.value.code == 2
    assert "--gospa-c" in capsys.readouterr().err


def test_an_empty_result_scores_nothing_without_failing(capsys, multi, tmp_path):
    empty = tmp_path / "empty.csv"
    write_tracks(empty, [])
    figures = run_json(capsys, multi[0], empty)
    assert figures["scans"] == 0 and figures["gospa_mean"] is None


def test_detections_and_a_plot_without_truth_or_error_panel(tmp_path):
    from bintrack.evaluation.plotting import detected_sensors, plot_scene

    sensors = [{"id": f"n{i}", "kind": "disk", "x": i % 20 * 5, "y": i // 20 * 5, "range": 4} for i in range(200)]
    sensors += [{"id": "s", "kind": "sector", "x": 50, "y": 50, "range": 4, "sectors": 6},
                {"id": "m", "kind": "motion", "x": 60, "y": 60, "period": 1},
                {"id": "L", "kind": "line", "a": 0.02, "b": 0.01}]
    dep = Deployment.model_validate({"name": "many", "units": "unit",
                                     "region": {"xmin": 0, "ymin": 0, "xmax": 100, "ymax": 50}, "sensors": sensors})
    events = [Event(0, "n1", 1), Event(1, "n2", 0), Event(2, "s", 0), Event(3, "m", 1), Event(4, "L", 1)]
    detected = detected_sensors(dep, events)
    assert detected == {"n1", "s", "L"}
    png = plot_scene(tmp_path / "scene.png", dep, tracks=[TrackRow(0, 0, 1, 1), TrackRow(1, 0, 9, 9)],
                     detected=detected, title="no truth")
    assert png.read_bytes().startswith(PNG_MAGIC)
