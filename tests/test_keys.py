import pytest

from bintrack.keys import Keys, ParsedKey, parse_key


def test_every_key_builds_and_parses_back():
    k = Keys("lab")
    cases = {
        k.raw("n1"): ParsedKey("lab", "raw", sensor="n1"),
        k.transition("n1"): ParsedKey("lab", "transition", sensor="n1"),
        k.state("n1"): ParsedKey("lab", "state", sensor="n1"),
        k.estimate("n1"): ParsedKey("lab", "estimate", sensor="n1"),
        k.fusion_reports(): ParsedKey("lab", "fusion_reports"),
        k.tracks(): ParsedKey("lab", "tracks"),
        k.laser_objects(): ParsedKey("lab", "laser_objects"),
        k.motion_velocity(): ParsedKey("lab", "motion_velocity"),
        k.deployment(): ParsedKey("lab", "deployment"),
        k.clock(): ParsedKey("lab", "clock"),
        k.eos(): ParsedKey("lab", "eos"),
        k.alive("replay", "r1"): ParsedKey("lab", "alive", service="replay", instance="r1"),
        k.progress("peer_agent", "p1"): ParsedKey("lab", "progress", service="peer_agent", instance="p1"),
        k.done("recorder", "r"): ParsedKey("lab", "done", service="recorder", instance="r"),
    }
    assert k.transition("n1") == "bintrack/lab/sensor/n1/transition"
    assert k.eos() == "bintrack/lab/control/eos"
    for key, parsed in cases.items():
        assert parse_key(key) == parsed


def test_wildcards_for_subscriptions():
    k = Keys()
    assert k.all() == "bintrack/default/**"
    assert k.transition() == "bintrack/default/sensor/*/transition"
    assert k.alive() == "bintrack/default/alive/*/*"


@pytest.mark.parametrize("key", ["other/net/tracks", "bintrack/net/nothing", "bintrack/net/sensor/a/b/c", "bintrack"])
def test_unknown_keys_are_rejected(key):
    with pytest.raises(ValueError):
        parse_key(key)


@pytest.mark.parametrize("bad", ["a/b", "*", "x$", ""])
def test_bad_network_names_are_rejected(bad):
    with pytest.raises(ValueError):
        Keys(bad)


@pytest.mark.parametrize("bad", ["a/b", "**", "x$", "", "a b"])
def test_bad_sensor_ids_are_rejected(bad):
    with pytest.raises(ValueError):
        Keys("n").transition(bad)
