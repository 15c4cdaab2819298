"""Corrupt recordings (issue: no silent loss): every chunk's CRC is checked; a bad one is
reported in one line, naming the first bad chunk and what was skipped, with exit 2 unless
``--salvage``; never a traceback, never a partial export without a word."""

from __future__ import annotations

import contextlib
import io
import random
from pathlib import Path

import pytest

from mcap.records import Chunk
from mcap.stream_reader import StreamReader

from bintrack.cli import main as cli
from bintrack.formats import open_dataset, read_tracks
from bintrack.keys import Keys
from bintrack.bus_payloads import TrackSet
from bintrack.message_codec import encode, encode_raw_sample
from bintrack.live.recording import RecordingWriter
from bintrack.live.recording_check import MCAP_MAGIC
from bintrack.pipeline import run_tracker
from bintrack.trackers import make_tracker

from support import DATASETS, bintrack, free_port

COPIES = 200
SEED = 39


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """darpa-grid-3's raw samples and mcmcda's track sets, in 8 KiB chunks (dozens of them)."""
    dataset = open_dataset(DATASETS / "darpa-grid-3")
    keys = Keys(dataset.deployment.name)
    path = tmp_path_factory.mktemp("recording") / "run.mcap"
    tracker = make_tracker("mcmcda", dataset.deployment)
    with RecordingWriter(path, dataset.deployment, keys.net, chunk_size=8192) as writer:
        for event in dataset.events():
            writer.write(keys.raw(event.sensor), event.t, encode_raw_sample(event.t, event.sensor, event.value))
        for out in run_tracker(dataset, tracker):
            if isinstance(out, TrackSet):
                writer.write(keys.tracks(), out.t, encode(out))
    return path


def export(path: Path, out: Path, *options: str) -> tuple[int, str]:
    """``bintrack export PATH --what tracks`` in this process: (exit status, stderr)."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = cli.main(["export", str(path), "--what", "tracks", "--out", str(out), *options])
    return code, err.getvalue()


def corrupt(data: bytes, rng: random.Random, how: str) -> bytes:
    data = bytearray(data)
    if how == "flip":
        for _ in range(rng.randint(1, 8)):
            i = rng.randrange(len(data))
            data[i] ^= 1 << rng.randrange(8)
    elif how == "truncate":
        data = data[:rng.randrange(8, len(data))]
    else:
        start = rng.randrange(len(data))
        end = min(len(data), start + rng.randint(1, 4096))
        data[start:end] = bytes(end - start)
    return bytes(data)


@pytest.mark.slow  # 400 exports: about a minute
def test_200_corrupted_copies_give_no_traceback_and_no_silent_partial_export(recording, tmp_path):
    expected = read_tracks(_exported(recording, tmp_path))
    rng = random.Random(SEED)
    original = recording.read_bytes()
    outcomes = {"refused": 0, "warned": 0, "whole": 0}
    for n in range(COPIES):
        how = ("flip", "truncate", "zero")[n % 3]
        copy = tmp_path / f"copy{n}.mcap"
        copy.write_bytes(corrupt(original, rng, how))
        out = tmp_path / f"copy{n}.csv"
        for options in ((), ("--salvage",)):
            code, err = export(copy, out, *options)  # a traceback would fail the test here
            lines = err.strip().splitlines()
            if code == 2:
                assert len(lines) == 1 and "error:" in lines[0], (n, how, err)
                assert options == () or "corrupt" in err or "not" in err or "missing" in err, (n, how, err)
                outcomes["refused"] += 1
                continue
            assert code == 0, (n, how, err)
            if "warning:" in err:
                outcomes["warned"] += 1
            else:  # not a word: then every row is there
                assert read_tracks(out) == expected, (n, how, options, err)
                outcomes["whole"] += 1
    # each kind of damage was met: refusals, and salvaged or torn copies that said so. (A random
    # flip that harms nothing is rare, about 1 in 80, and where it lands depends on the bytes,
    # which hold the wall-clock publish times: it is checked once, below, at a place known to be
    # such, the summary's copy of a schema, which the export does not read: the chunks hold theirs.)
    assert outcomes["refused"] and outcomes["warned"], outcomes
    harmless = bytearray(original)
    harmless[_summary_schema_end(original)] ^= 0x20
    copy = tmp_path / "harmless.mcap"
    copy.write_bytes(bytes(harmless))
    code, err = export(copy, tmp_path / "harmless.csv")
    assert code == 0 and "warning" not in err, err
    assert read_tracks(tmp_path / "harmless.csv") == expected


def _summary_schema_end(data: bytes) -> int:
    """The last byte of the first record of the MCAP summary section, a copy of a schema (the
    footer, before the closing magic, says where the summary starts; a record is an opcode, an
    8-byte length and its body)."""
    footer = len(data) - len(MCAP_MAGIC) - (1 + 8 + 20)
    assert data[footer] == 0x02, "no footer where the file should end"
    start = int.from_bytes(data[footer + 9:footer + 17], "little")
    assert data[start] == 0x03, "the summary does not start with a schema"
    return start + 9 + int.from_bytes(data[start + 1:start + 9], "little") - 1


def _exported(path: Path, tmp: Path) -> Path:
    out = tmp / "original.csv"
    code, err = export(path, out)
    assert code == 0 and "warning" not in err, err
    return out


def _bad_chunk(recording: Path, tmp: Path) -> Path:
    """A copy with one bit flipped inside the payload of its third chunk (CRC mismatch)."""
    data = bytearray(recording.read_bytes())
    chunks = [i for i in range(len(data)) if data[i] == 0x06]  # opcode of a chunk record
    from bintrack.live.recording_check import checked_scan

    copy = tmp / "bad.mcap"
    for i in chunks:  # the first place where a flip 200 bytes in damages the third chunk
        trial = bytearray(data)
        trial[i + 200] ^= 0x10
        copy.write_bytes(trial)
        with open(copy, "rb") as handle:
            damage = checked_scan(handle, keep_messages=False).damage
        if damage is not None and damage.chunk == 3 and damage.reason == "CRC mismatch":
            return copy
    raise AssertionError("no chunk to damage")


def test_a_bad_chunk_is_named_with_what_was_skipped_and_salvage_reads_the_rest(recording, tmp_path):
    expected = read_tracks(_exported(recording, tmp_path))
    bad = _bad_chunk(recording, tmp_path)
    out = tmp_path / "tracks.csv"
    code, err = export(bad, out)
    assert code == 2 and not out.exists()
    assert len(err.strip().splitlines()) == 1
    assert "corrupt recording: chunk 3 at byte" in err and "CRC mismatch" in err and "records skipped" in err
    assert "--salvage" in err
    code, err = export(bad, out, "--salvage")
    assert code == 0
    warning = [line for line in err.splitlines() if "warning:" in line]
    assert len(warning) == 1 and "chunk 3" in warning[0] and "records skipped" in warning[0]
    assert set(read_tracks(out)) <= set(expected)


def _chunk_starts(data: bytes) -> list[int]:
    handle = io.BytesIO(data)
    starts, at = [], len(MCAP_MAGIC)
    for record in StreamReader(handle, emit_chunks=True).records:
        if isinstance(record, Chunk):
            starts.append(at)
        at = handle.tell()
    return starts


@pytest.mark.parametrize("data_crc", ["kept", "zeroed"])
def test_a_chunk_whose_crc_is_zeroed_with_its_records_is_not_lost_unseen(recording, tmp_path, data_crc):
    """Zeroes from a chunk's CRC on (0 means "no CRC") empty it without failing its check: the
    data section's CRC finds it, and where that is zeroed too, the file's statistics do."""
    data = bytearray(recording.read_bytes())
    chunk = _chunk_starts(bytes(data))[12]  # raw samples only: no channel is defined in it
    crc_at = chunk + 1 + 8 + 8 + 8 + 8  # opcode, length, start and end times, uncompressed size
    data[crc_at:crc_at + 300] = bytes(300)
    if data_crc == "zeroed":
        end = bytes(data).rindex(b"\x0f" + (4).to_bytes(8, "little"))  # the DataEnd record
        data[end + 9:end + 13] = bytes(4)
    bad = tmp_path / "zeroed.mcap"
    bad.write_bytes(bytes(data))
    code, err = export(bad, tmp_path / "tracks.csv")
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "corrupt recording: the data section" in err and "records skipped" in err, err
    reason = "its CRC does not match" if data_crc == "kept" else "its statistics count"
    assert reason in err, err


def test_replay_view_and_up_refuse_a_corrupt_recording_once_in_one_line(recording, tmp_path):
    bad = _bad_chunk(recording, tmp_path)
    for args in (["replay", str(bad), "--speed", "0", "--connect", f"tcp/127.0.0.1:{free_port()}"],
                 ["view", str(bad), "--map-port", str(free_port())],
                 ["up", str(bad), "--speed", "0", "--exit-at-end", "--no-map", "--listen", f"tcp/127.0.0.1:{free_port()}"]):
        done = bintrack(*args)
        assert done.returncode == 2, (args[0], done.stderr)
        lines = [line for line in done.stderr.strip().splitlines() if "warning: --" not in line]
        assert len(lines) == 1 and "corrupt recording: chunk 3" in lines[0], (args[0], done.stderr)
        assert "Traceback" not in done.stderr and "restart" not in done.stderr
