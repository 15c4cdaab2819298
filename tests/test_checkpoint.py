"""Checkpoints are private pickles: written 0600 and atomically (a new file renamed, or into the
older of two slots of the file kept open), and refused with one line when someone else could
have written them (unpickling runs code) or when they are damaged."""

from __future__ import annotations

import os
import stat

import pytest

import pickle

from bintrack.live.checkpoint import Checkpointer, CheckpointRefused, load_checkpoint, save_checkpoint
from bintrack.live.checkpoint_slots import HEADER, RECORD


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


def test_each_save_goes_into_the_older_slot_so_a_write_cut_short_leaves_the_one_before(tmp_path):
    os.chmod(tmp_path, 0o700)
    saver = Checkpointer(str(tmp_path), "replay", "up1")
    for tick in range(1, 6):
        saver.save({"tick": tick})
    assert saver.load(dict) == {"tick": 5}
    # a kill cuts the sixth save short: its slot (the fifth's neighbour, holding the fourth) is spoilt
    saver.save({"tick": 6})
    start = HEADER.size + (6 % 2) * saver.slots.capacity + RECORD.size
    with open(saver.path, "r+b") as handle:
        handle.seek(start + 3)
        handle.write(b"\xff\xff")
    assert load_checkpoint(saver.path) == {"run": None, "state": {"tick": 5}}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["replay-up1.pickle"]


def test_a_checkpoint_that_outgrows_its_slot_is_written_anew_and_read_back(tmp_path):
    os.chmod(tmp_path, 0o700)
    saver = Checkpointer(str(tmp_path), "basestation", "up1")
    saver.save([0])
    small = saver.slots.capacity
    saver.save(list(range(10_000)))
    assert saver.slots.capacity > small
    assert saver.load(list) == list(range(10_000))
    assert stat.S_IMODE(os.stat(saver.path).st_mode) == 0o600
    saver.save([1, 2])
    assert saver.load(list) == [1, 2]


def test_a_plain_pickle_of_an_earlier_version_is_read(tmp_path):
    os.chmod(tmp_path, 0o700)
    path = tmp_path / "sensor_agent-up1.pickle"
    path.write_bytes(pickle.dumps({"run": "r", "state": {"tick": 2.5}}))
    os.chmod(path, 0o600)
    assert load_checkpoint(str(path)) == {"run": "r", "state": {"tick": 2.5}}


def test_a_sensor_agents_checkpoint_keeps_its_transitions_as_sent_and_reads_the_earlier_layout():
    from bintrack.bus_payloads import RawSample
    from bintrack.formats import open_dataset
    from bintrack.keys import Keys
    from bintrack.live.sensor_hosting import HostedSensors
    from bintrack.message_base import SCHEMA_VERSION
    from bintrack.transition_detector import TransitionDetector

    deployment = open_dataset("datasets/darpa-grid-1").deployment
    ids = [s.id for s in deployment.sensors][:3]

    def agent() -> tuple[HostedSensors, list[bytes]]:
        sent: list[bytes] = []
        return HostedSensors(Keys("n"), "agent-1", TransitionDetector(deployment, ids), ids,
                             lambda key, payload: sent.append(payload), lambda key, reason: None), sent

    first, sent = agent()
    for k, sid in enumerate(ids * 2):
        first.sensors[sid].handle(RawSample(t=0.5 * k, sensor=sid, value=1 - k // 3))
    saved = first.checkpoint(3.0)
    assert saved.recent == sent and len(sent) == 6  # as they went on the bus

    earlier = pickle.loads(pickle.dumps(saved))
    earlier.recent = [(SCHEMA_VERSION, *tr) for tr in first.recent]  # tuples, as earlier versions kept them
    for checkpoint in (saved, earlier):
        resumed, _ = agent()
        resumed.restore(checkpoint)
        assert list(resumed.recent) == list(first.recent)
        assert list(resumed.recent_payloads) == sent
        assert [tr.seq for tr in resumed.sensors[ids[0]].history] == [tr.seq for tr in first.sensors[ids[0]].history]
