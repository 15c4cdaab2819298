"""A full disk is a fault like any other: the recording on a small tmpfs. With the default
``--on-disk-full stop`` the recorder says so in one line and exits, ``up`` ends the stack, and
the file is finalised with everything that reached the disk before it filled; with ``pause``
event time is held until space is back, and the run then ends complete. Skipped, with one
line, where a tmpfs cannot be mounted (it needs root)."""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import pytest

from bintrack.formats import open_dataset, read_deployment
from bintrack.live.disk_full import DiskFull
from bintrack.live.recording import RecordingWriter, open_recording

from test_faults import DARPA3, Up, exported_tracks, grid_slice, offline_rows  # noqa: F401 (fixtures)


@pytest.fixture
def small_disk(tmp_path):
    """A folder on a tmpfs of ``size`` (a function of the size: mounts it)."""
    mounted = []

    def mount(size: str) -> Path:
        folder = tmp_path / f"disk{len(mounted)}"
        folder.mkdir()
        result = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(folder)],
                                capture_output=True, text=True)
        if result.returncode != 0:
            pytest.skip(f"cannot mount a tmpfs here: {(result.stderr or result.stdout).strip().splitlines()[-1:]}")
        mounted.append(folder)
        return folder

    yield mount
    for folder in mounted:
        subprocess.run(["umount", str(folder)], check=True)


# at --speed 0 on 64 kB the disk fills as the file is finalised, at 2 on 32 kB mid-run
@pytest.mark.parametrize("speed, size", [(0, "64k"), (2, "32k")])
def test_a_full_disk_ends_the_run_in_one_line_with_a_finalised_file(grid_slice, small_disk, speed, size):
    recording = small_disk(size) / "run.mcap"
    up = Up(str(grid_slice), "--tracker", "mcmcda", "--speed", str(speed), "--record", str(recording),
            "--exit-at-end")
    assert up.finish() == 1, up.log[-4000:]
    lines = [line for line in up.lines if "recorder: cannot write" in line]
    assert len(lines) == 1 and "Traceback" not in up.log, up.log[-4000:]
    assert "up: recorder could not write its recording" in up.log
    said = re.search(r"with (?:all |the )(\d+) messages|with (no) message", lines[0])
    assert said, lines[0]
    file = open_recording(recording)
    # it ends with its footer, not torn: finalised (without its index when the disk had no room)
    assert file.damage is None and (file.complete or "without its index" in lines[0]), lines[0]
    records = list(file.records())
    assert len(records) == (0 if said.group(2) else int(said.group(1))), lines[0]
    if speed == 0:  # the disk fills as the file is finalised: every message is in (mid-run, the
        assert records, lines[0]  # first flush may already fill it on a loaded machine)
    # everything that reached the disk: the dataset's samples up to the last one in the file
    raw = sorted((r.t, r.key) for r in records if r.kind == "raw")
    if not raw:
        return
    events = sorted(e.t for e in open_dataset(grid_slice).events() if e.t <= raw[-1][0])
    assert [t for t, _ in raw] == events


def test_with_pause_a_full_disk_holds_event_time_until_space_is_back(grid_slice, offline_rows, small_disk, tmp_path):
    disk = small_disk("256k")
    filler = disk / "filler"
    free = os.statvfs(disk)
    filler.write_bytes(b"\0" * (free.f_bavail * free.f_frsize - 48 * 1024))  # 48 kB left: less than the run needs
    recording = disk / "run.mcap"
    up = Up(str(grid_slice), "--tracker", "mcmcda", "--speed", "2", "--record", str(recording), "--exit-at-end",
            "--on-disk-full", "pause")
    up.wait_for(lambda line: "recorder: cannot write" in line and "holding event time" in line, "the pause")
    filler.unlink()
    up.wait_for(lambda line: "written again after" in line, "the recorder going on")
    assert up.finish() == 0, up.log[-4000:]
    assert "Traceback" not in up.log
    assert open_recording(recording).complete
    assert exported_tracks(recording, tmp_path) == offline_rows("mcmcda"), up.log[-4000:]


def test_a_file_whose_ending_cannot_be_written_is_named_with_why_and_the_space_left(tmp_path, caplog):
    # the last resort of a full disk (no room even for the 50-byte ending of an abandoned file)
    writer = RecordingWriter(tmp_path / "run.mcap", read_deployment(DARPA3 / "deployment.json"), "darpa-grid")
    writer.flush()

    def no_room():
        raise OSError(28, "No space left on device")

    writer.close = writer.abandon = no_room
    statuses = []
    with caplog.at_level("ERROR", logger="bintrack"):
        DiskFull("stop", statuses.append).end(writer, OSError(28, "No space left on device"))
    (line,) = [r.getMessage() for r in caplog.records]
    assert re.fullmatch(r"recorder: cannot write .*run\.mcap: No space left on device \(errno 28\); stopped: the file "
                        r"is not finalised \(its ending could not be written either: No space left on device "
                        r"\(errno 28\), \d+ bytes free\): it holds a readable prefix, no message; none lost", line), line
    assert statuses == [3]
