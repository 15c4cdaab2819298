"""Live equals offline: the whole stack on Zenoh gives the rows `bintrack track` gives."""

from __future__ import annotations

import argparse
import random
from pathlib import Path

import pytest
import yaml
import zenoh

from bintrack.cli import main as cli
from bintrack.cli import up_command
from bintrack.live.session_options import client_config, router_config
from bintrack.live.control_guard import control_attachment
from bintrack.formats import (
    TruthRow,
    open_dataset,
    read_objects,
    read_tracks,
    write_dataset,
)
from bintrack.keys import Keys
from bintrack.bus_payloads import Clock, EndOfStream
from bintrack.message_codec import decode, encode
from bintrack.pipeline import output_rows, run_tracker
from bintrack.live.recording import open_recording
from bintrack.cli.export_command import track_rows
from bintrack.trackers import BASELINES, make_tracker
from bintrack.transition_detector import TransitionDetector

from support import DATASETS, HUNG, REPO, bintrack, free_port, wait_until

DARPA3 = DATASETS / "darpa-grid-3"
LASER = DATASETS / "laser-testbed"


def live_and_offline(dataset: Path, tracker: str, tmp: Path, speed: str = "0",
                     exports: tuple[str, ...] = ("estimates", "tracks"), options: tuple[str, ...] = ()) -> None:
    """`up --exit-at-end` + `export` vs `track` (both with the tracker ``options``): the same
    rows for each of ``exports``."""
    recording = tmp / f"{tracker}.mcap"
    up = bintrack("up", str(dataset), "--speed", speed, "--tracker", tracker, *options, "--record", str(recording),
                  "--exit-at-end", "--listen", f"tcp/127.0.0.1:{free_port()}", "--no-view")
    assert up.returncode == 0, up.stderr[-3000:]
    offline = tmp / f"{tracker}-offline.csv"
    # `track` and `export` in this process: the same commands, without a Python start each
    assert cli.main(["track", str(dataset), "--tracker", tracker, *options, "--out", str(offline)]) == 0
    expected = read_tracks(offline)
    assert len(expected) > 20
    for what in exports:
        exported = tmp / f"{tracker}-{what}.csv"
        assert cli.main(["export", str(recording), "--what", what, "--out", str(exported)]) == 0
        assert read_tracks(exported) == expected, what


def simulated(tmp_path_factory, scenario: str, *options: str) -> Path:
    """A dataset of ``bintrack simulate SCENARIO OPTIONS`` in a fresh temporary folder."""
    folder = tmp_path_factory.mktemp(scenario) / "dataset"
    assert cli.main(["simulate", scenario, *options, "--out", str(folder)]) == 0
    return folder


@pytest.fixture(scope="module")
def uniform_dataset(tmp_path_factory) -> Path:
    return simulated(tmp_path_factory, "uniform-800", "--range", "60", "--trajectory", "random", "--seed", "5")


# Every peer tracker runs live on darpa-grid-3 below; on a random deployment the two whose
# estimates are geometry (a fitted line, intersected arcs) rather than weighted centroids.
@pytest.mark.parametrize("tracker", ("line-fit", "arc"))
def test_live_equals_offline_on_a_uniform_dataset(uniform_dataset, tracker, tmp_path):
    live_and_offline(uniform_dataset, tracker, tmp_path)


@pytest.fixture(scope="module")
def sector_dataset(tmp_path_factory) -> Path:
    return simulated(tmp_path_factory, "sector-300", "--sectors", "4", "--range", "70", "--trajectory", "random",
                     "--seed", "5")


def test_live_equals_offline_on_a_sector_dataset(sector_dataset, tmp_path):
    live_and_offline(sector_dataset, "sector", tmp_path)


@pytest.mark.parametrize("tracker", (*BASELINES, "arc", "sector"))
def test_live_equals_offline_on_darpa_grid_3(tracker, tmp_path):
    live_and_offline(DARPA3, tracker, tmp_path)


def test_live_equals_offline_for_mcmcda_on_darpa_grid_3(tmp_path):
    live_and_offline(DARPA3, "mcmcda", tmp_path, exports=("tracks",))


def test_live_equals_offline_for_mcmcda_with_a_fixed_lag(tmp_path):
    """`--lag`: the base station gives each scan's tracks 4 scans late, smoothed, and the rest
    at the end of the replay, as `track --lag` does."""
    live_and_offline(DARPA3, "mcmcda", tmp_path, exports=("tracks",), options=("--lag", "4"))


def test_up_of_a_recording_tracks_its_raw_samples_again_and_records_each_row_once(tmp_path):
    """`up RUN.mcap` replays the recording's raw samples (and truth), not its transitions and
    track sets, which the stack makes again: the offline rows, none twice, no duplicate dropped."""
    first = tmp_path / "first.mcap"
    live_and_offline(DARPA3, "mcmcda", tmp_path, exports=())
    (tmp_path / "mcmcda.mcap").rename(first)
    again = tmp_path / "again.mcap"
    up = bintrack("up", str(first), "--speed", "0", "--tracker", "mcmcda", "--record", str(again), "--exit-at-end",
                  "--listen", f"tcp/127.0.0.1:{free_port()}", "--no-view")
    assert up.returncode == 0, up.stderr[-3000:]
    assert "duplicate" not in up.stderr, up.stderr[-3000:]
    for name in ("first", "again"):
        assert cli.main(["export", str(tmp_path / f"{name}.mcap"), "--what", "tracks",
                         "--out", str(tmp_path / f"{name}.csv")]) == 0
    assert read_tracks(tmp_path / "again.csv") == read_tracks(tmp_path / "mcmcda-offline.csv")
    assert read_tracks(tmp_path / "first.csv") == read_tracks(tmp_path / "mcmcda-offline.csv")


def test_live_equals_offline_for_mcmcda_fed_by_arc_estimates(uniform_dataset, tmp_path):
    live_and_offline(uniform_dataset, "mcmcda", tmp_path, exports=("tracks",),
                     options=("--estimates", "arc", "--seed", "3"))


@pytest.fixture(scope="module")
def motion_dataset(tmp_path_factory) -> Path:
    return simulated(tmp_path_factory, "motion", "--nodes", "60", "--duration", "40", "--trajectory", "random-walk",
                     "--seed", "4")


@pytest.mark.parametrize("tracker", ("velocity-plane", "svm", "ppr", "motion-rw"))
def test_live_equals_offline_for_closer_farther_sensors(motion_dataset, tracker, tmp_path):
    live_and_offline(motion_dataset, tracker, tmp_path, exports=("velocity",), options=("--window", "8"))


def test_live_equals_offline_for_the_adaptive_basis_on_the_laser_testbed(tmp_path):
    recording = tmp_path / "laser.mcap"
    up = bintrack("up", str(LASER), "--speed", "0", "--tracker", "adaptive-basis", "--record", str(recording),
                  "--exit-at-end", "--listen", f"tcp/127.0.0.1:{free_port()}", "--no-view")
    assert up.returncode == 0, up.stderr[-3000:]
    offline, exported = tmp_path / "offline.csv", tmp_path / "live.csv"
    assert bintrack("track", str(LASER), "--tracker", "adaptive-basis", "--out", str(offline)).returncode == 0
    assert bintrack("export", str(recording), "--what", "objects", "--out", str(exported)).returncode == 0
    expected = read_objects(offline)
    assert len(expected) == 32
    assert read_objects(exported) == expected
    # every estimate, the revisions included, as the tracker gives them offline
    ds = open_dataset(LASER)
    offline_messages = [m for m in run_tracker(ds, make_tracker("adaptive-basis", ds.deployment))]
    live_messages = [m for _, m in open_recording(recording).messages({"laser_objects"})]
    key = lambda m: (m.object, m.revision or 0)  # noqa: E731
    assert any(m.revision for m in offline_messages)
    assert sorted(live_messages, key=key) == sorted(offline_messages, key=key)


@pytest.mark.slow
def test_live_equals_offline_in_real_time_on_a_20_s_slice(tmp_path):
    ds = open_dataset(DARPA3)
    events = [e for e in ds.events() if 10.0 <= e.t < 30.0]
    truth = [TruthRow(*r) for r in ds.truth() if 10.0 <= r.t < 30.0]
    folder = write_dataset(tmp_path / "slice", ds.deployment, events, truth)
    live_and_offline(folder, "equal-weight", tmp_path, speed="1")


def test_transitions_in_shuffled_order_within_the_lateness_bound(tmp_path, zenoh_router, services):
    """A test-side sensor agent publishes the transitions shuffled within 0.4 s of event time
    (lateness bound 1 s); peer agent, base station and recorder still give the offline rows."""
    ds = open_dataset(DARPA3)
    keys = Keys(ds.deployment.name)
    detector = TransitionDetector(ds.deployment)
    transitions = [tr for e in ds.events() if (tr := detector.update(e)) is not None]
    rng = random.Random(7)
    blocks: dict[int, list] = {}
    for tr in transitions:
        blocks.setdefault(int(tr.t // 0.4), []).append(tr)

    session = zenoh.open(client_config([zenoh_router]))
    progress: dict[str, float] = {}
    done: set[str] = set()
    entities = [
        session.declare_queryable(keys.deployment(), lambda q: q.reply(keys.deployment(), encode(ds.deployment))),
        session.declare_subscriber(keys.progress(), lambda s: progress.__setitem__(
            str(s.key_expr), decode(Clock, s.payload.to_bytes()).t)),
        session.declare_subscriber(keys.done(), lambda s: done.add(str(s.key_expr))),
        session.liveliness().declare_token(keys.alive("replay", "test")),  # clock and eos come from a replay
    ]
    control = control_attachment("replay", "test")
    recording = tmp_path / "shuffled.mcap"
    bus = ("--net", keys.net)
    procs = [services("peer_agent", "--tracker", "equal-weight", *bus, endpoint=zenoh_router),
             services("basestation", "--tracker", "equal-weight", *bus, endpoint=zenoh_router),
             services("recorder", "--out", str(recording), *bus, endpoint=zenoh_router)]
    try:
        wait_until(lambda: len({str(r.ok.key_expr) for r in session.liveliness().get(keys.alive(), timeout=HUNG)
                                if r.ok is not None and "/alive/replay/" not in str(r.ok.key_expr)}) >= 3,
                   "the three services' liveliness tokens", logs=procs, interval=0.1)

        def tick(t: float) -> None:
            session.put(keys.clock(), encode(Clock(t=t)), attachment=control)
            wait_until(lambda: len(progress) >= 3 and min(progress.values()) >= t, f"progress {t} from all three",
                       logs=procs, interval=0.002)

        for block in sorted(blocks):
            shuffled = blocks[block][:]
            rng.shuffle(shuffled)
            for tr in shuffled:
                session.put(keys.transition(tr.sensor), encode(tr))
            tick((block + 1) * 0.4)
        tick((max(blocks) + 2) * 0.4)
        session.put(keys.eos(), encode(EndOfStream(t=transitions[-1].t)), attachment=control)
        wait_until(lambda: any("/recorder/" in key for key in done), "the recorder's done", logs=procs)
    finally:
        for entity in entities:
            entity.undeclare()
        session.close()
        codes = [p.stop() for p in procs]
    assert codes == [0, 0, 0]
    expected = sorted(output_rows(run_tracker(ds, make_tracker("equal-weight", ds.deployment))))
    recorded = open_recording(recording)
    assert track_rows(recorded, "estimates") == expected
    assert track_rows(recorded, "tracks") == expected
    assert "late" not in procs[0].log


def test_compose_runs_the_commands_bintrack_up_runs():
    """docker-compose.yml is `bintrack up DIR --tracker mcmcda --loop --record … --foxglove` (mcmcda
    on the three-person grid), each service with a checkpoint under its own name."""
    compose = yaml.safe_load((REPO / "docker-compose.yml").read_text())["services"]
    parser = argparse.ArgumentParser()
    up_command.add_arguments(parser)
    args = parser.parse_args(["/data/datasets/darpa-grid-3", "--tracker", "mcmcda", "--speed", "1", "--loop",
                              "--record", "/data/out/recording.mcap", "--listen", "tcp/router:7447",
                              "--net", "darpa-grid", "--map-bind", "0.0.0.0", "--foxglove"])
    expected = up_command.planned_stack(args, "darpa-grid", 8080, state_dir="/data/state")
    assert {c.name for c in expected} | {"router"} == set(compose)
    for command in expected:
        assert compose[command.name]["command"] == [command.module, *command.args], command.name
    assert "--tracker" in compose["basestation"]["command"]
    assert compose["basestation"]["command"][compose["basestation"]["command"].index("--tracker") + 1] == "mcmcda"


@pytest.mark.parametrize(
    "args, words",
    [
        (["up", "--exit-at-end"], "needs a DIR"),
        (["up", str(DARPA3), "--record", "x.csv"], "must end in .mcap"),
        (["up", "/nonexistent/dataset"], "not a folder"),
    ],
)
def test_up_rejects_bad_options_with_one_line(args, words, capsys):
    assert cli.main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err


def test_up_reports_a_busy_port(capsys):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = zenoh.open(router_config([endpoint]))
    try:
        assert cli.main(["up", str(DARPA3), "--listen", endpoint]) == 2
    finally:
        router.close()
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "cannot start the router" in err
