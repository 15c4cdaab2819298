"""Faulty sensing and communication of paper 001 §5.6, applied to disk transitions.

* Wrong reports: each true transition to 1 is misreported with probability 5 % and each
  transition to 0 with probability 1 %; a misreport means the reported status stays what it
  was (so the node misses the target's arrival, or a departure).
* Packet collisions: two reports of nodes within communication range (2R) of each other that
  start closer in time than the collision gap (1e-4 s) collide and are both lost.
* Abandoned transmissions: a node that has a report within the transmission time (0.01 s)
  after a neighbour started transmitting hears it and abandons its own report.

Lost and abandoned reports simply do not appear in the output.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np
from scipy.spatial import cKDTree

from bintrack.formats import Event

MISS_ARRIVAL = 0.05
MISS_DEPARTURE = 0.01
COLLISION_GAP = 1e-4
TRANSMISSION_TIME = 0.01


def wrong_reports(events: Iterable[Event], rng: np.random.Generator,
                  p_to_one: float = MISS_ARRIVAL, p_to_zero: float = MISS_DEPARTURE) -> list[Event]:
    """Reported transitions of disk sensors given their true ones (``events`` in time order,
    values 0/1, any number of sensors): each true transition is missed with probability
    ``p_to_one`` (to 1) or ``p_to_zero`` (to 0); a report is made only when the reported
    status changes."""
    reported: dict[str, int] = {}
    out = []
    for event in events:
        miss = rng.random() < (p_to_one if event.value == 1 else p_to_zero)
        if not miss and reported.get(event.sensor, 0) != event.value:
            reported[event.sensor] = event.value
            out.append(event)
    return out


def packet_faults(events: Iterable[Event], positions: Mapping[str, tuple[float, float]], comm_range: float,
                  collision_gap: float = COLLISION_GAP, transmission_time: float = TRANSMISSION_TIME) -> list[Event]:
    """The reports that get through (``events`` in time order; ``positions`` in units).

    Reports are handled in time order. A report starting less than ``collision_gap`` s after a
    transmission of a neighbour (distance ≤ ``comm_range``) collides: both are lost. Otherwise a
    report starting less than ``transmission_time`` s after a neighbour's transmission is
    abandoned. Otherwise it is transmitted."""
    events = list(events)
    ids = sorted({e.sensor for e in events})
    index = {sensor: k for k, sensor in enumerate(ids)}
    neighbours: list[set[int]] = [set() for _ in ids]
    if len(ids) > 1:
        tree = cKDTree(np.array([positions[sensor] for sensor in ids], dtype=float))
        for i, j in tree.query_pairs(comm_range):
            neighbours[i].add(j)
            neighbours[j].add(i)
    last_sent: dict[int, int] = {}  # node -> index in events of its latest transmission
    lost = np.zeros(len(events), dtype=bool)
    sent = np.zeros(len(events), dtype=bool)
    for k, event in enumerate(events):
        node = index[event.sensor]
        heard = [last_sent[n] for n in neighbours[node]
                 if n in last_sent and event.t - events[last_sent[n]].t < transmission_time]
        colliding = [q for q in heard if event.t - events[q].t < collision_gap]
        if colliding:
            lost[colliding] = True
            lost[k] = True
        elif heard:
            continue
        sent[k] = True
        last_sent[node] = k
    return [e for e, s, x in zip(events, sent, lost) if s and not x]
