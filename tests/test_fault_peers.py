"""The fault matrix of the peers' stack (equal-weight: the peer agents run the tracker, the base
station relays their estimates): the relay killed alone (it used to lose what it held), and the
pairs with the peer agent or the relay in them, killed together at ``--speed 0``, each at a kill
time of its own (tests/test_fault_pairs.py says what each run must give)."""

from __future__ import annotations

import pytest

from test_fault_pairs import check_rows, field, kill_time, offline, run_with_a_kill  # noqa: F401 (fixtures)

PEER_FAULTS = [("basestation",), ("peer_agent", "basestation"), ("sensor_agent", "peer_agent"),
               ("peer_agent", "recorder"), ("basestation", "recorder")]


@pytest.mark.parametrize("victims, seed", [pytest.param(v, seed, id="+".join(v))
                                           for seed, v in enumerate(PEER_FAULTS, start=11)])
def test_peer_stack_services_killed_together(field, offline, victims, seed, tmp_path):
    # kills up to 20 s: at --speed 0 the peers' stack can play 15 s of event time between two
    # progress lines, and a kill meant for 29 s then landed after the end of the replay
    up, live = run_with_a_kill(field, tmp_path, "equal-weight", 0, victims, kill_time(seed, 6.0, 20.0))
    check_rows(up, live, offline("equal-weight"))
