import json
from pathlib import Path

import pytest

from bintrack.cli import main as cli
from bintrack.formats import (
    Event,
    FormatError,
    ObjectRow,
    TrackRow,
    TruthRow,
    iter_events,
    open_dataset,
    read_deployment,
    read_objects,
    read_tracks,
    read_truth,
    write_dataset,
    write_objects,
    write_tracks,
)
from bintrack.deployment_model import Deployment

DEPLOYMENT = {
    "format": "bintrack.deployment/1",
    "name": "mixed",
    "units": "ft",
    "region": {"xmin": 0, "ymin": 0, "xmax": 16, "ymax": 8},
    "sensors": [
        {"id": "d1", "kind": "disk", "x": 1, "y": 1, "range": 3, "range_in": 2.7, "pd": 0.7, "pfa": 0.05, "period": 0.5},
        {"id": "s1", "kind": "sector", "x": 4, "y": 4, "range": 3, "sectors": 4, "offset": 0.5},
        {"id": "m1", "kind": "motion", "x": 5, "y": 5, "period": 1},
        {"id": "L1", "kind": "line", "x": 2, "y": 0},
        {"id": "L2", "kind": "line", "a": 0.1, "b": 0.05},
    ],
    "calibration": {"passes": [{"pass": 1, "t_entry": 0, "entry": [0, 0], "t_exit": 11.3, "exit": [16, 0]}]},
}

GOOD_EVENTS = "t,sensor,value\n0.5,d1,1\n0.7,s1,3\n1.0,m1,-1\n1.2,L1,1\n1.5,s1,-1\n2.0,d1,0\n"


def make(folder: Path, events: str = GOOD_EVENTS, deployment: dict | str = DEPLOYMENT) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    text = deployment if isinstance(deployment, str) else json.dumps(deployment, indent=1)
    (folder / "deployment.json").write_text(text)
    (folder / "events.csv").write_text(events)
    return folder


def test_reads_every_field_of_every_sensor_kind(tmp_path):
    ds = open_dataset(make(tmp_path / "d"))
    sensors = ds.deployment.by_id()
    assert sensors["d1"].range_in == 2.7 and sensors["d1"].period == 0.5 and sensors["d1"].pfa == 0.05
    assert sensors["s1"].sectors == 4 and sensors["s1"].offset == 0.5
    assert sensors["L2"].a == 0.1 and sensors["L1"].x == 2
    assert ds.deployment.calibration.passes[0].exit == (16, 0)
    assert list(ds.events())[1] == Event(0.7, "s1", 3)


def test_dataset_round_trip(tmp_path):
    dep = Deployment.model_validate(DEPLOYMENT)
    events = [Event(0.5, "d1", 1), Event(1.0, "m1", 1)]
    truth = [TruthRow(0.0, "1", 0.0, 0.0), TruthRow(1.0, "1", 1.5, 0.25)]
    write_dataset(tmp_path / "rt", dep, events, truth)
    ds = open_dataset(tmp_path / "rt")
    assert ds.deployment == dep
    assert list(ds.events()) == events
    assert read_truth(tmp_path / "rt" / "truth.csv") == truth


def test_events_stream_lazily(tmp_path):
    folder = make(tmp_path / "lazy", GOOD_EVENTS + "3.0,nope,1\n")
    stream = iter_events(folder / "events.csv", read_deployment(folder / "deployment.json"))
    assert next(stream) == Event(0.5, "d1", 1)  # read before the bad last row is reached
    with pytest.raises(FormatError, match="unknown sensor"):
        list(stream)


@pytest.mark.parametrize(
    "events, line, field, words",
    [
        ("t,sensor,value\n0.5,d1,1\n0.7,s1\n", 3, "value", "truncated row"),
        ("t,sensor,value\n0.5,d1,yes\n", 2, "value", "not a number"),
        ("t,sensor,value\nnan,d1,1\n", 2, "t", "not a finite number"),
        ("t,sensor,value\n0.5,d9,1\n", 2, "sensor", "unknown sensor id"),
        ("t,sensor,value\n0.5,d1,1\n0.4,d1,0\n", 3, "t", "earlier than the previous"),
        ("t,sensor,value\n0.5,d1,2\n", 2, "value", "disk sensor reports 0 or 1"),
        ("t,sensor,value\n0.5,s1,4\n", 2, "value", "-1..3"),
        ("t,sensor,value\n0.5,m1,0\n", 2, "value", "+1 or -1"),
        ("t,sensor,value\n0.5,L1,0\n", 2, "value", "line sensor"),
        ("t,sensor,value\n,d1,1\n", 2, "t", "missing value"),
        ("t,sensor\n0.5,d1\n", 1, "value", "missing column"),
        ("t,sensor,value\n0.5,d1,1.5\n", 2, "value", "not an integer"),
    ],
)
def test_malformed_events_name_file_line_and_field(tmp_path, events, line, field, words):
    folder = make(tmp_path / "bad", events)
    with pytest.raises(FormatError) as info:
        list(open_dataset(folder).events())
    err = info.value
    assert (err.line, err.field) == (line, field)
    assert words in err.message
    assert str(err).startswith(f"{folder / 'events.csv'}:{line}: {field}: ")


def _without(key: str, index: int = 0) -> dict:
    dep = json.loads(json.dumps(DEPLOYMENT))
    del dep["sensors"][index][key]
    return dep


@pytest.mark.parametrize(
    "deployment, line, field, words",
    [
        (_without("range"), 12, "sensors[0].range", "missing field"),
        (_without("sectors", 1), 23, "sensors[1].sectors", "missing field"),
        ({**DEPLOYMENT, "units": "yards"}, 1, "units", "Input should be"),
        ({k: v for k, v in DEPLOYMENT.items() if k != "format"}, 1, "format", "missing field"),
        ('{"format": "bintrack.deployment/1",\n "name": "x", \n "units": "m"\n', 4, "json", ""),
        (json.dumps({**DEPLOYMENT, "sensors": [{**DEPLOYMENT["sensors"][0], "x": "NaN"}]}), 1, "sensors[0].x", ""),
        ({**DEPLOYMENT, "sensors": [{"id": "q", "kind": "camera"}]}, 12, "sensors[0].kind", "unknown sensor kind"),
    ],
)
def test_malformed_deployment_names_line_and_field(tmp_path, deployment, line, field, words):
    folder = make(tmp_path / "bad", deployment=deployment)
    with pytest.raises(FormatError) as info:
        open_dataset(folder)
    assert (info.value.line, info.value.field) == (line, field)
    assert words in info.value.message


def test_results_round_trip(tmp_path):
    tracks = [TrackRow(1.0, 0, 1.5, 2.5, None, None), TrackRow(2.0, 3, 1.0, 2.0, 0.5, -0.25)]
    write_tracks(tmp_path / "tracks.csv", tracks)
    assert read_tracks(tmp_path / "tracks.csv") == tracks
    objects = [ObjectRow(1, 0.5, 11.0, 0.0, 1.0, 16.0, 2.0, 1.4, 0.1)]
    write_objects(tmp_path / "objects.csv", objects)
    assert read_objects(tmp_path / "objects.csv") == objects


def test_a_failed_write_leaves_the_old_file_intact(tmp_path):
    path = tmp_path / "tracks.csv"
    write_tracks(path, [TrackRow(1.0, 0, 1.0, 1.0)])
    before = path.read_bytes()

    def rows():
        yield TrackRow(2.0, 0, 2.0, 2.0)
        raise RuntimeError("tracker failed")

    with pytest.raises(RuntimeError):
        write_tracks(path, rows())
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tracks.csv"]


@pytest.mark.parametrize("events", ["t,sensor,value\n0.5,d1,1\n0.7,s1\n", "t,sensor,value\n0.5,zz,1\n"])
def test_cli_exits_2_with_one_line(tmp_path, capsys, events):
    folder = make(tmp_path / "bad", events)
    out = tmp_path / "tracks.csv"
    assert cli.main(["track", str(folder), "--tracker", "equal-weight", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "events.csv:" in err
    assert not out.exists()
