"""Every command, given a bad path or option, says so in one line and exits with status 2.

The walk covers missing folders, folders given where a file is wanted (and files where a
folder is), unwritable targets (under /proc, which even root cannot write) and files that are
not what they claim. Each case runs ``bintrack`` in this process (no traceback can hide: an
uncaught exception fails the test) and checks stderr holds exactly one line.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import pytest

from bintrack.argtypes import positive_float
from bintrack.cli import main as cli
from support import HUNG, REPO, bintrack

DARPA3 = REPO / "datasets" / "darpa-grid-3"
UNWRITABLE = "/proc/bintrack-nowhere"


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("bad-paths")
    a_file = root / "a-file.txt"
    a_file.write_text("not a folder\n")
    folder_named_mcap = root / "folder.mcap"
    folder_named_mcap.mkdir()
    not_mcap = root / "not-a-recording.mcap"
    not_mcap.write_bytes(b"not an mcap file")
    tracks = root / "tracks.csv"
    assert cli.main(["track", str(DARPA3), "--tracker", "equal-weight", "--out", str(tracks), "--no-progress"]) == 0
    return {"FILE": a_file, "DIRMCAP": folder_named_mcap, "NOTMCAP": not_mcap, "TRACKS": tracks,
            "MISSING": root / "missing" / "dir", "TMP": root}


CASES = [
    # simulate
    ["simulate", "darpa-grid", "--out", "{FILE}"],
    ["simulate", "darpa-grid", "--out", f"{UNWRITABLE}/ds"],
    # track
    ["track", "{MISSING}", "--tracker", "equal-weight"],
    ["track", "{FILE}", "--tracker", "equal-weight"],
    ["track", str(DARPA3), "--tracker", "equal-weight", "--out", "{MISSING}/tracks.csv"],
    ["track", str(DARPA3), "--tracker", "equal-weight", "--out", "{TMP}"],
    ["track", str(DARPA3), "--tracker", "equal-weight", "--out", f"{UNWRITABLE}/tracks.csv"],
    ["track", str(DARPA3), "--tracker", "equal-weight", "--out", "{FILE}/tracks.csv"],
    # eval
    ["eval", "{MISSING}", "{TRACKS}"],
    ["eval", str(DARPA3), "{MISSING}/tracks.csv"],
    ["eval", str(DARPA3), "{TMP}"],
    ["eval", str(DARPA3), "{TRACKS}", "--plot", "{MISSING}/plot.png"],
    ["eval", str(DARPA3), "{TRACKS}", "--plot", "{TMP}"],
    # schema
    ["schema", "--out", "{MISSING}/schema.json"],
    ["schema", "--out", "{TMP}"],
    ["schema", "--out", f"{UNWRITABLE}/schema.json"],
    # up and demo (each refuses before it starts anything)
    ["up", "{MISSING}"],
    ["up", "{FILE}"],
    ["up", str(DARPA3), "--record", "{MISSING}/run.mcap"],
    ["up", str(DARPA3), "--record", "{DIRMCAP}"],
    ["up", str(DARPA3), "--record", f"{UNWRITABLE}/run.mcap"],
    ["up", str(DARPA3), "--secure", "--certs", "{MISSING}", "--listen", "tls/127.0.0.1:1"],
    ["up", str(DARPA3), "--speed", "-1"],
    ["demo", "{MISSING}"],
    ["demo", "{FILE}"],
    ["demo", "--out", "{FILE}"],
    ["demo", "--out", f"{UNWRITABLE}/demo"],
    # replay, record, export, view
    ["replay", "{MISSING}"],
    ["replay", "{NOTMCAP}"],
    ["record", "--out", "{MISSING}/run.mcap"],
    ["record", "--out", "{DIRMCAP}"],
    ["record", "--out", f"{UNWRITABLE}/run.mcap"],
    ["record", "--out", "{TMP}/run.csv"],
    ["export", "{MISSING}/run.mcap", "--what", "tracks", "--out", "x.csv"],
    ["export", "{NOTMCAP}", "--what", "tracks", "--out", "x.csv"],
    ["view", "{MISSING}/run.mcap"],
    ["view", "{NOTMCAP}"],
    # import, calibrate
    ["import", "{FILE}", "--sensors", "{MISSING}/s.csv", "--period", "0.5", "--range", "0.7", "--out", "{TMP}/imp"],
    ["import", "{MISSING}/m.txt", "--sensors", "{FILE}", "--period", "0.5", "--range", "0.7", "--out", "{TMP}/imp"],
    ["calibrate", "{MISSING}", "--out", "{TMP}/cal"],
    ["calibrate", str(DARPA3), "--out", "{FILE}", "--boot", "0"],
    ["calibrate", str(DARPA3), "--out", f"{UNWRITABLE}/cal", "--boot", "0"],
    # certs
    ["certs", "--out", "{FILE}"],
    ["certs", "--out", f"{UNWRITABLE}/certs"],
    ["certs", "--out", "{TMP}/certs", "--ca", "{MISSING}"],
]


def _ids(case: list[str]) -> str:
    return " ".join(a.replace(str(DARPA3), "DS") for a in case)


@pytest.mark.parametrize("case", CASES, ids=[_ids(c) for c in CASES])
def test_a_bad_path_is_one_line_and_status_2(case, files, capsys):
    args = [a.format(**files) for a in case]
    status = cli.main(args)
    err = capsys.readouterr().err.strip()
    assert status == 2, f"{args}: status {status}, stderr:\n{err}"
    assert len(err.splitlines()) == 1 and f"bintrack {case[0]}" in err, err
    assert "Traceback" not in err


@pytest.fixture(scope="module")
def recording(files) -> Path:
    """A tiny finished recording (for export's output paths)."""
    from bintrack.live.recording import RecordingWriter
    from bintrack.bus_payloads import Clock
    from bintrack.deployment_model import Deployment
    from bintrack.message_codec import encode

    path = files["TMP"] / "tiny.mcap"
    deployment = Deployment.model_validate_json((DARPA3 / "deployment.json").read_text())
    with RecordingWriter(path, deployment, "darpa-grid") as writer:
        writer.write("bintrack/darpa-grid/clock", 1.0, encode(Clock(t=1.0)))
    return path


@pytest.mark.parametrize("out", [
    ["--what", "tracks", "--out", "{MISSING}/tracks.csv"],
    ["--what", "tracks", "--out", "{TMP}"],
    ["--what", "tracks", "--out", f"{UNWRITABLE}/tracks.csv"],
    ["--foxglove", "{MISSING}/x.mcap"],
    ["--foxglove", "{DIRMCAP}"],
])
def test_export_to_a_bad_path_is_one_line_and_status_2(out, files, recording, capsys):
    status = cli.main(["export", str(recording), *(a.format(**files) for a in out)])
    err = capsys.readouterr().err.strip()
    assert status == 2 and len(err.splitlines()) == 1 and "bintrack export" in err, err


def test_bintrack_alone_lists_the_commands():
    result = bintrack()
    assert result.returncode == 0, result.stderr
    for command in cli.SUBCOMMANDS:
        assert f"\n    {command} " in result.stdout, command


def test_an_old_option_name_still_works_and_warns_once(capsys):
    # --view-port is now --map-port: accepted, one warning line, then the usual refusal of --speed -1
    status = cli.main(["up", str(DARPA3), "--view-port", "1", "--view-port", "2", "--speed", "-1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2
    assert [line for line in err if "warning" in line] == ["bintrack up: warning: --view-port is now --map-port"]


@pytest.mark.parametrize("package, args", [
    ("matplotlib", ["--plot", "{TMP}/plot.png"]),   # the plot
    ("motmetrics", []),                             # IDF1
])
def test_a_package_the_installation_leaves_out_is_one_line_and_status_2(package, args, files):
    # the container image leaves both out (deploy/Dockerfile): none of its services needs them
    code = ("import sys; sys.modules[sys.argv[1]] = None\n"  # as if not installed: importing it fails
            "from bintrack.cli.main import main; sys.exit(main(sys.argv[2:]))")
    argv = ["eval", str(DARPA3), str(files["TRACKS"]), *(a.format(**files) for a in args)]
    result = subprocess.run([sys.executable, "-c", code, package, *argv], capture_output=True, text=True, cwd=REPO,
                            timeout=HUNG)
    err = result.stderr.strip()
    assert result.returncode == 2 and len(err.splitlines()) == 1, err
    assert err == (f"bintrack eval: error: this needs the Python package {package}, which this installation "
                   f"leaves out (pip install {package})")


@pytest.mark.parametrize("text", ["-1", "0", "nan", "inf", "-inf"])
def test_a_positive_option_says_the_same_for_every_value_it_refuses(text):
    """--gospa-c -1 once said "must be a number >= 0", though 0 is refused too."""
    with pytest.raises(argparse.ArgumentTypeError, match=r"must be a finite number > 0, got"):
        positive_float(text)
    with pytest.raises(argparse.ArgumentTypeError, match="not a number: 'x'"):
        positive_float("x")
    assert positive_float("0.5") == 0.5
