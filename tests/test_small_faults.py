"""The small faults of the second no-silent-loss round (row 12): each gives one line and the
right exit status, or works — keys open to other users, a permissive umask, a deeply nested
deployment.json, a network name that cannot be a key, a ``bintrack/`` folder where ``up`` runs."""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from bintrack.formats import TruthRow, open_dataset, write_dataset
from bintrack.live.secure_profile import exposed_keys

from support import DATASETS, HUNG, bintrack, free_port

DARPA3 = DATASETS / "darpa-grid-3"
BINTRACK = Path(sys.executable).parent / "bintrack"  # the installed command: no folder of the cwd on its path


@pytest.fixture(scope="module")
def slice_dataset(tmp_path_factory) -> Path:
    """darpa-grid-3 from 10 to 25 s: a short run."""
    ds = open_dataset(DARPA3)
    return write_dataset(tmp_path_factory.mktemp("slice") / "slice", ds.deployment,
                         [e for e in ds.events() if 10.0 <= e.t < 25.0],
                         [TruthRow(*r) for r in ds.truth() if 10.0 <= r.t < 25.0])


def one_line(stderr: str) -> str:
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in stderr, stderr
    return lines[0]


def test_a_deployment_nested_100000_deep_is_one_line(tmp_path):
    folder = tmp_path / "deep"
    shutil.copytree(DARPA3, folder)
    (folder / "deployment.json").write_text("[" * 100_000 + "]" * 100_000)
    result = bintrack("track", str(folder), "--tracker", "arc", "--out", str(tmp_path / "t.csv"))
    assert result.returncode == 2
    assert "deployment.json: json: nested too deeply" in one_line(result.stderr)


def test_a_deployment_named_bad_name_is_one_line_in_up(tmp_path):
    folder = tmp_path / "bad"
    shutil.copytree(DARPA3, folder)
    text = (folder / "deployment.json").read_text().replace('"name": "darpa-grid"', '"name": "bad/name*"')
    assert "bad/name*" in text
    (folder / "deployment.json").write_text(text)
    result = bintrack("up", str(folder), "--exit-at-end", "--no-map", "--listen", f"tcp/127.0.0.1:{free_port()}")
    assert result.returncode == 2
    line = one_line(result.stderr)
    assert "'bad/name*' cannot be a key-expression chunk" in line and "--net" in line


def test_certs_under_umask_000_leave_the_folder_0700_and_the_keys_0600(tmp_path):
    out = tmp_path / "certs"
    result = subprocess.run([str(BINTRACK), "certs", "--out", str(out), "--roles", "viewer"], capture_output=True,
                            text=True, timeout=HUNG, preexec_fn=lambda: os.umask(0))
    assert result.returncode == 0, result.stderr
    assert stat.S_IMODE(out.stat().st_mode) == 0o700
    for key in ("ca-key.pem", "viewer-key.pem"):
        assert stat.S_IMODE((out / key).stat().st_mode) == 0o600
    assert exposed_keys(out) is None


def test_up_from_a_folder_holding_a_bintrack_folder_runs_the_installed_services(slice_dataset, tmp_path):
    decoy = tmp_path / "bintrack"
    (decoy / "services").mkdir(parents=True)
    for init in (decoy / "__init__.py", decoy / "services" / "__init__.py"):
        init.write_text("raise ImportError('the bintrack/ folder of the current directory was imported')\n")
    result = subprocess.run([str(BINTRACK), "up", str(slice_dataset), "--speed", "0", "--tracker", "equal-weight",
                             "--exit-at-end", "--no-map", "--listen", f"tcp/127.0.0.1:{free_port()}"],
                            cwd=tmp_path, capture_output=True, text=True, timeout=HUNG)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "current directory was imported" not in result.stderr and "restarted" not in result.stderr


def test_secure_with_keys_open_to_others_warns_in_one_line(slice_dataset, tmp_path):
    certs = tmp_path / "certs"
    assert subprocess.run([str(BINTRACK), "certs", "--out", str(certs)], capture_output=True,
                          timeout=HUNG).returncode == 0
    assert exposed_keys(certs) is None
    for key in certs.glob("*-key.pem"):
        key.chmod(0o666)
    certs.chmod(0o777)
    result = subprocess.run([str(BINTRACK), "up", str(slice_dataset), "--speed", "0", "--tracker", "equal-weight",
                             "--exit-at-end", "--no-map", "--secure", "--certs", str(certs), "--listen",
                             f"tls/127.0.0.1:{free_port()}"], capture_output=True, text=True, timeout=HUNG)
    assert result.returncode == 0, result.stderr[-3000:]
    warnings = [line for line in result.stderr.splitlines() if "readable by others" in line]
    assert len(warnings) == 1
    assert "router-key.pem 666" in warnings[0] and f"the folder {certs} is 777" in warnings[0]
