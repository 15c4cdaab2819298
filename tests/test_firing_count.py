"""Real PIR: a count of the people from how many sensors fire (``bintrack.trackers.multi.firing_count``)
and the targets the fit seeks when that count holds more people than it placed (step 7 of
``bintrack.trackers.multi.target_fit``)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from bintrack.deployment_model import Deployment, DiskSensor, Region
from bintrack.errors import TrackerConfigError
from bintrack.trackers.multi.firing_count import FiringCount
from bintrack.trackers.multi.fusion import GridFusion, Scan, ScanFusion
from bintrack.trackers.multi.fusion_config import FusionConfig
from bintrack.trackers.multi.mcmcda_config import MCMCDAConfig
from bintrack.trackers.multi.pir_settings import pir_settings
from bintrack.trackers.multi.track_expectation import Expectation

SPACING = 1.3  # m between sensors, as on the recording's ceiling


def _firings(counts, a: float, b: float, seed: int) -> np.ndarray:
    """Firing sensors per scan for a room holding ``counts`` people: Poisson of mean a·n + b."""
    rng = np.random.default_rng(seed)
    return rng.poisson(a * np.asarray(counts) + b)


def test_the_count_follows_the_people_from_the_firings_alone():
    counts = [1] * 40 + [2] * 60 + [4] * 80 + [3] * 60 + [1] * 40
    errors = []
    for seed in range(5):
        count = FiringCount(0.02, floor=1.6, false_alarms=0.2)
        estimate = []
        for k in _firings(counts, 1.6, 0.2, seed):
            count.update(int(k))
            estimate.append(int(np.argmax(count.belief)))
        errors.append(np.abs(np.array(estimate) - counts)[20:].mean())  # after the first 10 s
    assert np.mean(errors) < 0.5
    # a slope 40 % too low counts too many people
    count = FiringCount(0.02, floor=1.0, false_alarms=0.2)
    for k in _firings([4] * 100, 1.6, 0.2, 0):
        count.update(int(k))
    assert int(np.argmax(count.belief)) > 4


def test_beyond_is_how_many_more_people_are_at_least_as_likely_as_not():
    count = FiringCount(0.02, floor=1.5, false_alarms=0.1)
    for _ in range(30):
        count.update(6)  # three people at 1.5 firings each, scan after scan
    assert int(np.argmax(count.belief)) == 4 or int(np.argmax(count.belief)) == 3
    assert count.beyond(0) >= 3 and count.beyond(1) == count.beyond(0) - 1
    assert count.beyond(5) == 0 and count.beyond(30) == 0


def test_the_count_holds_more_people_than_its_prior_reaches():
    # a hall of 45 people at 1.5 firings each: a filter that holds 100 follows them, one that
    # holds only its prior's 30 cannot
    firings = _firings([45] * 150, 1.5, 0.2, 0)
    wide, narrow = FiringCount(0.02, floor=1.5, false_alarms=0.2, most=100), FiringCount(0.02, floor=1.5, false_alarms=0.2)
    for k in firings:
        wide.update(int(k))
        narrow.update(int(k))
    assert abs(int(np.argmax(wide.belief)) - 45) <= 3 and wide.beyond(40) >= 2
    assert int(np.argmax(narrow.belief)) == 30 and narrow.beyond(30) == 0
    # the fusion holds twice the deployment's sensors
    room = _line(20)
    assert len(ScanFusion(room, _pir(room)).count.belief) == 41


def test_a_count_checkpointed_with_its_move_matrix_goes_on():
    """A filter pickled before it held more than 30 people kept its move as a 31 × 31 matrix
    and no switch; it goes on as a new one would."""
    new = FiringCount(0.02, floor=1.5, false_alarms=0.2)
    s, n = 0.02, 31
    move = np.diag(np.full(n, 1.0 - s)) + np.diag(np.full(n - 1, s / 2), 1) + np.diag(np.full(n - 1, s / 2), -1)
    state = {k: v for k, v in new.__dict__.items() if k != "switch"}
    state["_move"] = move / move.sum(axis=1, keepdims=True)
    old = FiringCount.__new__(FiringCount)
    old.__setstate__(state)
    for k in _firings([2] * 30 + [5] * 30, 1.5, 0.2, 3):
        assert old.update(int(k)) == pytest.approx(new.update(int(k)))
    assert old.belief == pytest.approx(new.belief) and old.beyond(0) == new.beyond(0)


def test_placed_people_set_the_firings_per_person():
    count = FiringCount(0.02, floor=1.0, false_alarms=0.0)
    assert count.a == pytest.approx(1.0)
    count.placed(np.array([2.0] * 20))  # as many people as the floor's prior weighs
    assert count.a == pytest.approx(1.5)


def _line(n: int = 7) -> Deployment:
    sensors = [DiskSensor(id=f"s{i}", x=i * SPACING, y=1.0, range=1.2, pd=0.7, pfa=0.003, period=0.5, hold=0.0)
               for i in range(n)]
    return Deployment(name="room", units="m", region=Region(xmin=-1, ymin=0, xmax=n * SPACING, ymax=2), sensors=sensors)


def _pir(room: Deployment) -> FusionConfig:
    return pir_settings(room, FusionConfig(), MCMCDAConfig())[0]


def test_real_pir_counts_the_people_and_other_deployments_do_not():
    room = _line()
    assert (_pir(room).count_switch, _pir(room).count_threshold, _pir(room).count_soft) == (0.02, 1, 0.9)
    assert ScanFusion(room, _pir(room)).count is not None
    plain = room.model_copy(update={"sensors": [s.model_copy(update={"hold": None}) for s in room.sensors]})
    assert _pir(plain).count_switch is None and ScanFusion(plain, _pir(plain)).count is None


def _track(x: float) -> list[Expectation]:
    return [Expectation(x=x, y=1.0, sigma=0.3, vx=0.0, vy=0.0, reports=10, unreported=1)]


def test_a_person_one_sensor_saw_is_placed_only_when_the_count_asks():
    """A track's person stands between sensors 0 and 1, which fire, and sensor 5, 6.5 m away,
    fires alone: n_d = 2 leaves it out (and a track's blob is split only at 8 nats), unless the
    count holds one more person."""
    room = _line()
    grid = GridFusion(room, _pir(room))
    pattern = np.array([1, 1, 0, 0, 0, 1, 0])
    assert len(grid.reports(pattern, _track(0.65))) == 1
    assert len(grid.reports(pattern, _track(0.65), beyond=lambda placed: 0)) == 1
    reports = grid.reports(pattern, _track(0.65), beyond=lambda placed: 1)
    assert len(reports) == 2
    assert min(abs(r.x - 5 * SPACING) for r in reports) < 0.5


def test_a_walkers_far_firing_needs_no_second_person():
    """A track expects its person between sensors 0 and 1; 0, 1 and 2 fire. The disks (1.2 m)
    leave sensor 2 unexplained, and the track's blob is split only at 8 nats. The count's extra
    target there is kept unless the Gaussian footprints that judge it are wide enough to explain
    sensor 2 by the same person: at σ = 1.2 R they are (a second person gains under 2 nats), at
    σ = 0.5 R they are not."""
    room = _line()
    pattern = np.array([1, 1, 1, 0, 0, 0, 0])

    def reports(spread, beyond):
        return GridFusion(room, replace(_pir(room), count_soft=spread)).reports(pattern, _track(0.9), beyond=beyond)

    assert len(reports(None, None)) == 1
    assert len(reports(None, lambda placed: 1)) == 2
    assert len(reports(0.5, lambda placed: 1)) == 2
    assert len(reports(1.2, lambda placed: 1)) == 1


def test_the_scan_fusion_feeds_the_count_and_asks_it():
    """Scan after scan, a track's person between sensors 0 and 1 and a lone firing at sensor 5:
    the count learns the firings per person from the people placed and, holding two people,
    has the lone firing reported; without the count it never is."""
    room = _line()
    lone = np.array([1, 1, 0, 0, 0, 1, 0], dtype=bool)
    counted, uncounted = ScanFusion(room, _pir(room)), ScanFusion(room, replace(_pir(room), count_switch=None))
    a = counted.count.a
    for k in range(20):
        scan = Scan(t=0.5 * k, detecting=lone)
        out, plain = counted.fuse(scan, _track(0.65)), uncounted.fuse(scan, _track(0.65))
        assert len(plain.reports) == 1
    assert counted.count.a != a
    assert int(np.argmax(counted.count.belief)) == 2 and len(out.reports) == 2


@pytest.mark.parametrize("field, value", [("count_switch", 0.0), ("count_switch", 1.0), ("count_threshold", 0),
                                          ("count_soft", -1.0)])
def test_a_bad_count_setting_is_refused(field, value):
    with pytest.raises(TrackerConfigError, match=field):
        ScanFusion(_line(), replace(_pir(_line()), **{field: value}))
