"""Checkpoints are private pickles: written 0600 and atomically, and refused with one line when
someone else could have written them (unpickling runs code) or when they are damaged."""

from __future__ import annotations

import os
import stat

import pytest

from bintrack.live.checkpoint import CheckpointRefused, load_checkpoint, save_checkpoint


def test_a_checkpoint_round_trips_and_is_private(tmp_path):
    os.chmod(tmp_path, 0o700)
    path = str(tmp_path / "basestation-up1.pickle")
    save_checkpoint(path, {"t": 17.5, "anchors": [1, 2, 3]})
    assert load_checkpoint(path) == {"t": 17.5, "anchors": [1, 2, 3]}
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o600
    assert not os.path.exists(path + ".tmp")
    assert load_checkpoint(str(tmp_path / "absent.pickle")) is None


@pytest.mark.parametrize("what", ["file", "folder"])
def test_a_checkpoint_others_could_write_is_refused_unread(tmp_path, what):
    folder = tmp_path / "state"
    folder.mkdir(mode=0o700)
    path = str(folder / "sensor_agent-up1.pickle")
    save_checkpoint(path, {"t": 3.0})
    os.chmod(path if what == "file" else folder, 0o666 if what == "file" else 0o777)
    with pytest.raises(CheckpointRefused, match="writable by group or others"):
        load_checkpoint(path)


def test_a_damaged_checkpoint_is_refused_with_its_reason(tmp_path):
    os.chmod(tmp_path, 0o700)
    path = str(tmp_path / "recorder-up1.pickle")
    save_checkpoint(path, list(range(1000)))
    with open(path, "r+b") as handle:
        handle.truncate(20)
    with pytest.raises(CheckpointRefused, match="unreadable"):
        load_checkpoint(path)
