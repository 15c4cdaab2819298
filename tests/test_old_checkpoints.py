"""A checkpoint taken before the trackers and the messages were split into one module per concept
still loads (:mod:`bintrack.live.moved_classes`), and its trackers go on as trackers
run from the start.

``data/checkpoint-before-moves/drivers.pickle.gz`` was pickled by that older version (commit
a614eb7): per tracker, ``{"events": n, "detector": TransitionDetector, "driver": TrackerDriver}``
after the first n events of its dataset, run as ``bintrack track`` runs them — mcmcda with the
arc tracker's estimates (``n_mc`` 100) on a small simulated grid kept beside it (``bintrack
simulate darpa-grid --grid 4 --people 2 --duration 60 --seed 3``), and adaptive-basis on the
shipped laser testbed.

The pickled state's floats were computed with the numpy of that day; the same state computed
again with another numpy can differ in the last bits (seen: 1e-14 m in mcmcda, 4e-8 in
adaptive-basis's fitted lines), so the continuation is held to the same messages, identities and
counts exactly, and to 1e-6 in every float.
"""

from __future__ import annotations

import gzip
import math
import os

import msgpack
import pytest

from bintrack.formats import open_dataset
from bintrack.live.checkpoint import load_checkpoint
from bintrack.message_codec import encode
from bintrack.pipeline import TrackerDriver
from bintrack.trackers import TrackerOptions, make_tracker
from bintrack.trackers.laser.phase3_frame import Frame
from bintrack.trackers.multi.fusion import ScanFusion
from bintrack.trackers.multi.fusion_config import FusionConfig
from bintrack.trackers.multi.mcmcda_config import MCMCDAConfig
from bintrack.trackers.multi.mcmcda_window import ChainTrack
from bintrack.transition_detector import TransitionDetector
from support import DATASETS, REPO

DATA = REPO / "tests" / "data" / "checkpoint-before-moves"
CASES = {
    "mcmcda": (DATA, TrackerOptions(estimates="arc", n_mc=100)),
    "adaptive-basis": (DATASETS / "laser-testbed", TrackerOptions()),
}


def _feed(detector, driver, events) -> list:
    out = []
    for event in events:
        transition = detector.update(event)
        if transition is not None:
            out += driver.advance(transition.t)
            driver.push(transition)
    return out


def _fields(messages: list) -> list:
    """Every field of ``messages`` in order, as the bus carries them (nested lists flattened)."""
    def walk(value):
        if isinstance(value, dict):
            return [("key", k) for k in value] + [v for k in value for v in walk(value[k])]
        if isinstance(value, (list, tuple)):
            return [("length", len(value))] + [v for item in value for v in walk(item)]
        return [value]
    return [v for m in messages for v in walk(msgpack.unpackb(encode(m)))]


def _same(resumed: list, expected: list) -> bool:
    a, b = _fields(resumed), _fields(expected)
    return len(a) == len(b) and all(
        math.isclose(x, y, rel_tol=1e-6, abs_tol=1e-6) if isinstance(x, float) and isinstance(y, float) else x == y
        for x, y in zip(a, b))


@pytest.fixture(scope="module")
def old_checkpoint(tmp_path_factory) -> dict:
    folder = tmp_path_factory.mktemp("state")
    os.chmod(folder, 0o700)
    path = folder / "basestation-old.pickle"
    path.write_bytes(gzip.decompress((DATA / "drivers.pickle.gz").read_bytes()))
    os.chmod(path, 0o600)
    return load_checkpoint(str(path))


@pytest.mark.parametrize("name", CASES)
def test_a_checkpoint_of_the_version_before_the_moves_resumes_as_a_run_from_the_start(old_checkpoint, name):
    saved = old_checkpoint[name]
    folder, options = CASES[name]
    dataset = open_dataset(folder)
    events = list(dataset.events())
    n = saved["events"]
    assert 0 < n < len(events)
    tracker = make_tracker(name, dataset.deployment, options)
    if name == "mcmcda":  # the checkpoint goes on with the fit it was taken with: over the union of
        # the disks, copies with no evidence bar
        tracker.fusion = ScanFusion(dataset.deployment, FusionConfig(multiplicity=False, expected_gain=1.0,
                                                                     expected_split_gain=4.0, shared_support=None))
    if name == "adaptive-basis":
        tracker.revisions = None  # the checkpoint's version made no revisions: it resumes without them
    detector, driver = TransitionDetector(dataset.deployment), TrackerDriver(tracker)
    _feed(detector, driver, events[:n])
    expected = _feed(detector, driver, events[n:]) + driver.finish()
    resumed = _feed(saved["detector"], saved["driver"], events[n:]) + saved["driver"].finish()
    assert len(expected) > 5 and [type(m) for m in resumed] == [type(m) for m in expected]
    assert _same(resumed, expected), (resumed, expected)


def test_the_old_classes_are_found_at_their_new_homes(old_checkpoint):
    mcmcda = old_checkpoint["mcmcda"]["driver"].tracker.mcmcda
    assert type(mcmcda.config) is MCMCDAConfig
    assert mcmcda._tracks and all(type(t) is ChainTrack for t in mcmcda._tracks)
    assert type(old_checkpoint["adaptive-basis"]["driver"].tracker.frame) is Frame
