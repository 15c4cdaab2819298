"""Regions (DESIGN §9): deployment.json's optional regions, which sensors each region takes, the
region keys, and the merge of the regions' tracks into the network's picture (pure parts)."""

from __future__ import annotations

import json

import pytest

from bintrack.evaluation.track_agreement import agreement
from bintrack.formats import FormatError, TrackRow, parse_deployment
from bintrack.keys import Keys, parse_key
from bintrack.bus_payloads import Track, TrackSet
from bintrack.deployment_model import Region
from bintrack.message_codec import decode, encode
from bintrack.regions import WHOLE, RegionMap, grid_areas, grid_shape
from bintrack.trackers.multi.region_merge import MergeConfig, RegionMerge


def deployment_json(regions=None, spacing: float = 5.0, side: int = 12) -> dict:
    sensors = [{"id": f"n{i}_{j}", "kind": "disk", "x": i * spacing, "y": j * spacing, "range": 8.0}
               for i in range(side) for j in range(side)]
    data = {"format": "bintrack.deployment/1", "name": "field", "units": "m",
            "region": {"xmin": 0, "ymin": 0, "xmax": (side - 1) * spacing, "ymax": (side - 1) * spacing},
            "sensors": sensors}
    if regions is not None:
        data["regions"] = regions
    return data


def deployment(regions=None):
    return parse_deployment(json.dumps(deployment_json(regions)))


HALVES = [{"name": "west", "xmin": 0, "ymin": 0, "xmax": 27.5, "ymax": 55},
          {"name": "east", "polygon": [[27.5, 0], [55, 0], [55, 55], [27.5, 55]]}]


def test_without_regions_the_field_is_one_region():
    regions = RegionMap(deployment())
    assert regions.names == [WHOLE]
    assert len(regions.own_sensors(WHOLE)) == 144


def test_rectangles_and_polygons_own_every_sensor_once_and_take_a_border_band():
    regions = RegionMap(deployment(HALVES))
    west, east = regions.own_sensors("west"), regions.own_sensors("east")
    assert sorted(west + east) == sorted(s.id for s in regions.deployment.sensors)  # a partition
    assert all(regions.deployment.by_id()[s].x <= 27.5 for s in west)
    taken = regions.taken_sensors("west")  # within three ranges (24 m) of x ≤ 27.5
    assert set(west) < set(taken)
    assert {regions.deployment.by_id()[s].x for s in taken} == {5.0 * i for i in range(11)}  # x ≤ 50 < 51.5
    assert set(regions.taken_sensors("west", band=0.0)) == set(west)
    assert regions.owner(27.5, 10) == "west" and regions.owner(27.6, 10) == "east"
    assert regions.owner(-3, -3) == "west"  # outside every region: the nearest
    assert regions.neighbours("west") == ["east"]
    part = regions.sub_deployment("east")
    assert {s.id for s in part.sensors} == set(regions.taken_sensors("east")) and part.region == regions.deployment.region


@pytest.mark.parametrize("regions, field, message", [
    ([{"name": "a", "xmin": 0, "ymin": 0, "xmax": 10}], "regions[0]", "needs xmin, ymin, xmax, ymax or a polygon"),
    ([{"name": "a", "polygon": [[0, 0], [1, 1]]}], "regions[0]", "a polygon needs at least 3 vertices"),
    ([{"name": "a/b", "xmin": 0, "ymin": 0, "xmax": 1, "ymax": 1}], "regions[0].name", "String should match"),
    ([{"name": "a", "xmin": 0, "ymin": 0, "xmax": 1, "ymax": 1}] * 2, "(top level)", "duplicate region name"),
])
def test_bad_regions_get_a_one_line_error_naming_the_field(regions, field, message):
    with pytest.raises(FormatError) as caught:
        deployment(regions)
    text = str(caught.value)
    assert field in text and message in text and "\n" not in text


def test_a_polygon_that_crosses_itself_is_refused():
    bow_tie = [{"name": "bow", "polygon": [[0, 0], [10, 10], [10, 0], [0, 10]]}]
    with pytest.raises(ValueError, match="crosses itself"):
        RegionMap(deployment(bow_tie))


def test_grid_areas_cut_the_field():
    areas = grid_areas(Region(xmin=0, ymin=0, xmax=40, ymax=20), 2, 2)
    assert [a.name for a in areas] == ["r0c0", "r0c1", "r1c0", "r1c1"]
    assert (areas[3].xmin, areas[3].ymin, areas[3].xmax, areas[3].ymax) == (20, 10, 40, 20)
    assert grid_shape(16) == (4, 4) and grid_shape(4) == (2, 2) and grid_shape(6) == (3, 2) and grid_shape(1) == (1, 1)


def test_region_keys_round_trip():
    keys = Keys("field")
    assert keys.region_tracks("r0c1") == "bintrack/field/region/r0c1/tracks"
    for build, kind in ((keys.region_tracks, "region_tracks"), (keys.region_reports, "region_reports"),
                        (keys.region_progress, "region_progress"), (keys.region_alive, "region_alive")):
        parsed = parse_key(build("r0c1"))
        assert (parsed.kind, parsed.region, parsed.net) == (kind, "r0c1", "field")
    with pytest.raises(ValueError):
        keys.region_tracks("a/b")


def test_a_track_set_of_before_regions_still_decodes_and_the_new_fields_default():
    old = {"version": 1, "t": 1.0, "tracker": "mcmcda", "tracks": [{"track": 3, "x": 1.0, "y": 2.0}]}
    import msgpack

    tracks = decode(TrackSet, msgpack.packb(old))
    assert tracks.tracks[0].stale is False and tracks.tracks[0].region is None
    stale = Track(track=1, x=0, y=0, region="west", stale=True)
    assert decode(TrackSet, encode(TrackSet(t=0, tracker="m", tracks=[stale]))).tracks[0] == stale


# --------------------------------------------------------------------------- the merge


def scan(t: float, *tracks: tuple[int, float, float]) -> TrackSet:
    return TrackSet(t=t, tracker="mcmcda", tracks=[Track(track=k, x=x, y=y, vx=1.0, vy=0.0) for k, x, y in tracks])


def crossing(merge: RegionMerge, t_end: float = 20.0, west_until: float = 40.0, east_from: float = 15.0):
    """A target walking east along y = 20 at 1 m/s from x = 10 (t = 0): west tracks it (local id
    1) while x < ``west_until``, east (local id 7) once x > ``east_from``; scans every 0.5 s."""
    out = []
    t = 0.0
    while t <= t_end:
        x = 10 + t
        west = [(1, x + 0.1, 20.0)] if x < west_until else []
        east = [(7, x - 0.1, 20.0)] if x > east_from else []
        merge.add("west", scan(t, *west))
        merge.add("east", scan(t, *east))
        out += merge.progress("west", t) + merge.progress("east", t)
        t += 0.5
    return out


def test_a_target_crossing_the_border_is_shown_once_under_one_identity():
    merge = RegionMerge(RegionMap(deployment(HALVES)))
    merge.back("west"), merge.back("east")
    merged = crossing(merge, t_end=30.0)
    assert [m.t for m in merged] == [0.5 * k for k in range(61)]
    assert all(len(m.tracks) == 1 for m in merged)  # the band's duplicate is never shown twice
    assert {m.tracks[0].track for m in merged} == {0}
    regions = [m.tracks[0].region for m in merged]
    assert regions[0] == "west" and regions[-1] == "east"
    assert regions.index("east") == 36  # x = 28 ≈ the border at 27.5


def test_a_hand_over_without_overlap_matches_the_ended_track_by_position_and_time():
    merge = RegionMerge(RegionMap(deployment(HALVES)), MergeConfig(gate=5.0, handover=5.0))
    merge.back("west"), merge.back("east")
    merged = crossing(merge, t_end=30.0, west_until=27.5, east_from=29.0)  # 1 s with nobody tracking it
    ids = {tr.track for m in merged for tr in m.tracks}
    assert ids == {0}
    assert sum(not m.tracks for m in merged) == 4  # t = 17.5 … 19 s


def test_two_targets_far_apart_keep_two_identities():
    merge = RegionMerge(RegionMap(deployment(HALVES)))
    merge.back("west"), merge.back("east")
    merge.add("west", scan(0.0, (1, 5.0, 5.0)))
    merge.add("east", scan(0.0, (1, 50.0, 50.0)))
    merge.progress("west", 0.0)
    (merged,) = merge.progress("east", 0.0)
    assert sorted((t.track, t.region) for t in merged.tracks) == [(0, "east"), (1, "west")] or \
        sorted((t.track, t.region) for t in merged.tracks) == [(0, "west"), (1, "east")]


def test_the_merge_waits_for_every_live_region_and_a_lost_one_turns_stale():
    merge = RegionMerge(RegionMap(deployment(HALVES)))
    merge.back("west"), merge.back("east")
    merge.add("west", scan(0.0, (1, 5.0, 5.0)))
    assert merge.progress("west", 0.0) == []  # east has not said it is done with t = 0
    merge.add("east", scan(0.0, (4, 50.0, 50.0)))
    (first,) = merge.progress("east", 0.0)
    east_id = next(t.track for t in first.tracks if t.region == "east")
    merge.add("west", scan(0.5, (1, 5.5, 5.0)))
    assert merge.progress("west", 0.5) == []
    (second,) = merge.lost("east")  # no longer waited for
    stale = [t for t in second.tracks if t.stale]
    assert [(t.track, t.region, t.x, t.y) for t in stale] == [(east_id, "east", 50.0, 50.0)]
    assert [t.stale for t in second.tracks if t.region == "west"] == [False]
    merge.back("east")
    merge.add("east", scan(1.0, (4, 50.5, 50.0)))
    merge.add("west", scan(1.0, (1, 6.0, 5.0)))
    assert merge.progress("west", 1.0) == []
    (third,) = merge.progress("east", 1.0)
    assert not any(t.stale for t in third.tracks) and {t.track for t in third.tracks} == {east_id, 1 - east_id}


def test_watch_shows_the_region_and_staleness_of_merged_tracks():
    from bintrack.cli.watch_command import format_trackset

    merged = TrackSet(t=1.0, tracker="mcmcda", tracks=[Track(track=0, x=1, y=2, region="r0c0"),
                                                        Track(track=1, x=3, y=4, region="r1c1", stale=True)])
    assert format_trackset(merged) == ("t=1.000 tracker=mcmcda tracks=2 | #0 (1.00, 2.00) v=(-, -) r0c0 | "
                                       "#1 (3.00, 4.00) v=(-, -) r1c1 stale")


def test_an_identity_made_while_the_owner_was_cut_off_gives_way_to_the_owners_when_it_is_back():
    """A target walking west: east tracks it, east's link is cut, and more than the hand-over
    time later west's border band picks it up on east's side (a new, provisional identity).
    When east is back and shows its track beside west's, the target carries east's identity
    again, also once it is on west's side: the identity is kept across the cut."""
    merge = RegionMerge(RegionMap(deployment(HALVES)), MergeConfig(gate=5.0, handover=5.0))
    merge.back("west"), merge.back("east")
    out = []
    t = 0.0
    while t <= 20.0:
        x = 40.0 - t
        if t == 4.5:
            out += merge.lost("east")
        if t == 12.5:
            merge.back("east")
        east_live = t < 4.5 or t >= 12.5
        merge.add("west", scan(t, *([(1, x - 0.1, 20.0)] if t >= 10.0 else [])))
        if east_live:
            merge.add("east", scan(t, (7, x + 0.1, 20.0)))
        out += merge.progress("west", t) + (merge.progress("east", t) if east_live else [])
        t += 0.5
    live = {m.t: {tr.track for tr in m.tracks if not tr.stale} for m in out}
    assert all(live[k] == {0} for k in live if k < 4.5)
    assert all(live[k] == {1} for k in live if 10.0 <= k < 12.5)  # east cut off: west's own identity
    assert all(live[k] == {0} for k in live if k >= 12.5), live  # east back: its identity, on both sides
    assert max(live) == 20.0 and 40.0 - 20.0 < 27.5  # the target ends on west's side


def test_a_target_that_left_a_cut_off_region_takes_back_its_identity_from_the_regions_late_scans():
    """A target walking west: east tracks it and is cut off at t = 4.5 s; the target crosses
    into west's own half during the cut, where west picks it up (a new identity, provisional:
    east could have been tracking it there). East is back at t = 25 s, when the target is out
    of its reach, so east never shows it live again; but east's scans of the cut, come in after
    their time was merged, show its track on the target: from then on the target carries east's
    identity again."""
    merge = RegionMerge(RegionMap(deployment(HALVES)), MergeConfig(gate=5.0, handover=5.0, reach=8.0))
    merge.back("west"), merge.back("east")
    out = []
    t = 0.0
    while t <= 30.0:
        x = 40.0 - t
        if t == 4.5:
            out += merge.lost("east")
        if t == 25.0:
            merge.back("east")
            for k in range(10, 50):  # east's scans of the cut: its track followed the target to x = 21
                merge.add("east", scan(k / 2, *([(7, 40.0 - k / 2 + 0.1, 20.0)] if k / 2 <= 19.0 else [])))
        east_live = t < 4.5 or t >= 25.0
        merge.add("west", scan(t, *([(1, x - 0.1, 20.0)] if t >= 14.0 else [])))
        if east_live:
            merge.add("east", scan(t, *([(7, x + 0.1, 20.0)] if x >= 21.0 else [])))
        out += merge.progress("west", t) + (merge.progress("east", t) if east_live else [])
        t += 0.5
    live = {m.t: {tr.track for tr in m.tracks if not tr.stale} for m in out}
    assert all(live[k] == {0} for k in live if k < 4.5)
    assert all(live[k] == {1} for k in live if 14.0 <= k < 25.0), live  # on west's side, east cut off
    assert all(live[k] == {0} for k in live if k >= 25.0), live  # east's late scans: its identity again
    assert not any(tr.stale for m in out if m.t >= 25.0 for tr in m.tracks)


def test_a_regions_late_scans_leave_identities_alone_where_no_provisional_target_lies():
    """The same walk, but west's track is never near east's late track (it walks 10 m north of
    it): west's identity stays."""
    merge = RegionMerge(RegionMap(deployment(HALVES)), MergeConfig(gate=5.0, handover=5.0, reach=8.0))
    merge.back("west"), merge.back("east")
    out = []
    for k in range(61):
        t = k / 2
        if t == 4.5:
            out += merge.lost("east")
        if t == 25.0:
            merge.back("east")
            for j in range(10, 50):
                merge.add("east", scan(j / 2, *([(7, 40.0 - j / 2, 20.0)] if j / 2 <= 19.0 else [])))
        east_live = t < 4.5 or t >= 25.0
        merge.add("west", scan(t, *([(1, 40.0 - t, 30.0)] if t >= 14.0 else [])))
        if east_live:
            merge.add("east", scan(t, *([(7, 40.0 - t, 20.0)] if t < 4.5 else [])))
        out += merge.progress("west", t) + (merge.progress("east", t) if east_live else [])
    live = {m.t: {tr.track for tr in m.tracks if not tr.stale} for m in out}
    assert all(live[k] == {0} for k in live if k < 4.5)
    assert all(live[k] == {1} for k in live if k >= 14.0), live


def test_a_region_silent_behind_a_stale_token_is_taken_for_gone_until_it_reports_again():
    """The merge's router kept the token of region east's base station after the link to it was
    cut: east's progress stays behind the clock. After 10 s of wall time more than the hold
    (plus the lead) behind it is taken for gone, once; a progress report from it brings it back."""
    from bintrack.live.region_departures import RegionDepartures
    wall = [0.0]
    departures = RegionDepartures("merge", now=lambda: wall[0])
    assert departures.silent({"west": 10.0, "east": 10.0}, 12.0, 0.5) == []  # 2 s behind: within the hold
    assert departures.silent({"west": 14.0, "east": 10.0}, 14.0, 0.5) == []  # east behind from now
    wall[0] += 9.9
    assert departures.silent({"west": 24.0, "east": 10.0}, 24.0, 0.5) == []
    wall[0] += 0.1
    assert departures.silent({"west": 24.0, "east": 10.0, "north": float("-inf")}, 24.0, 0.5) == ["east"]
    departures.went("east", 1)
    assert departures.silent({"west": 25.0, "east": 10.0}, 25.0, 0.5) == []  # once
    assert departures.tick(25.0, 0.5) == [] and departures.tick(27.5, 0.5) == ["east"]  # given up after the hold
    assert not departures.reports("west")
    assert departures.reports("east") and not departures.reports("east")  # back, once


def test_agreement_counts_switches_as_clear_mot_does():
    """Two people walking 0.8 m apart, tracked by both outputs under steady identities: noise
    of 0.5 m puts the other output's tracks nearer the wrong reference track at some scans. Pairs
    decided afresh each scan count those as switches; CLEAR MOT's kept pairs do not. An identity
    that ends and comes back under another one is a switch either way."""
    reference, other = [], []
    for k in range(20):
        t = 0.5 * k
        reference += [TrackRow(t, 1, float(k), 0.0, 2.0, 0.0), TrackRow(t, 2, float(k), 0.8, 2.0, 0.0)]
        wobble = 0.5 if k % 3 == 0 else 0.0  # every third scan the two tracks lean into each other
        later = 7 if k >= 12 else 5  # the second person's identity in the other output changes at scan 12
        other += [TrackRow(t, 4, float(k), wobble, 2.0, 0.0), TrackRow(t, later, float(k), 0.8 - wobble, 2.0, 0.0)]
    result = agreement(reference, other)
    assert result.count_equal == result.scans == 20 and result.within(0.5) == 1.0
    assert result.switches == 1  # identity 5 → 7, once
    assert result.switches_redecided > result.switches  # the wobbles counted as well
