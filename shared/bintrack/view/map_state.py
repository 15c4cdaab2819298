"""The picture a map page needs, kept bounded: what a page opened now must be sent.

:class:`MapState` takes the items of :mod:`.map_messages` in arrival order and keeps the
latest of each thing (tracks, fused reports, each node's estimate, each sensor's status) and
the recent past a page draws as tails (track scans and truth within ``tail`` seconds of event
time). Every collection has a fixed bound, so the state never grows with the run's length.
Pure: no I/O, no clock but event time.
"""

from __future__ import annotations

from collections import OrderedDict, deque
from typing import Any

from bintrack.deployment_model import Deployment
from bintrack.view.map_messages import Item, deployment_item

DEFAULT_TAIL = 30.0        # s of event time drawn behind each track and truth target
MAX_SCANS = 2000           # track scans kept for the tails, whatever ``tail`` says
MAX_TRUTH_POINTS = 2000    # truth points kept for the dashed paths
MAX_OBJECTS = 100          # laser objects kept
MAX_KEYED = 4096           # sensors / nodes / targets remembered when the deployment does not bound them


class MapState:
    """The latest picture for a page: feed items with :meth:`apply`, read :meth:`snapshot`."""

    def __init__(self, deployment: Deployment | None = None, tail: float = DEFAULT_TAIL):
        self.tail = tail
        self.deployment: Item | None = None
        self._known: set[str] | None = None
        self.clear()
        if deployment is not None:
            self.set_deployment(deployment)

    def clear(self) -> None:
        """Forget everything but the deployment (a recording seeked elsewhere)."""
        self.t: float | None = None
        self.sensors: OrderedDict[str, list] = OrderedDict()   # id -> [value, t]
        self.scans: deque[Item] = deque(maxlen=MAX_SCANS)
        self.reports: Item | None = None
        self.estimates: OrderedDict[str, Item] = OrderedDict()
        self.objects: deque[Item] = deque(maxlen=MAX_OBJECTS)
        self.velocity: Item | None = None
        self.truth: deque[Item] = deque(maxlen=MAX_TRUTH_POINTS)
        self.ended: float | None = None

    def set_deployment(self, deployment: Deployment) -> Item:
        self.deployment = deployment_item(deployment)
        self._known = {s.id for s in deployment.sensors}
        for sensor in [s for s in self.sensors if s not in self._known]:
            del self.sensors[sensor]
        return self.deployment

    @property
    def latest_tracks(self) -> Item | None:
        return self.scans[-1] if self.scans else None

    def apply(self, item: Item) -> bool:
        """Take one item; False (and nothing kept) for an item of an unknown sensor or node."""
        kind = item["k"]
        t = item.get("t")
        if kind == "sensor":
            if not self._bounded(self.sensors, item["id"]):
                return False
            self.sensors[item["id"]] = [item["v"], t]
        elif kind == "tracks":
            self.scans.append(item)
        elif kind == "reports":
            self.reports = item
        elif kind == "estimate":
            if not self._bounded(self.estimates, item["node"]):
                return False
            self.estimates[item["node"]] = item
        elif kind == "object":
            self._object(item)
        elif kind == "velocity":
            self.velocity = item
        elif kind == "truth":
            self.truth.append(item)
        if kind == "eos":
            self.ended = t
        elif self.ended is not None and t is not None and t > self.ended:
            self.ended = None   # a looping replay started its next pass
        if t is not None and (self.t is None or t > self.t):
            self.t = t
        self._trim()
        return True

    def _object(self, item: dict) -> None:
        """Keep a laser object's latest revision: a revision replaces its earlier estimate in place."""
        for i, have in enumerate(self.objects):
            if have.get("n") == item.get("n"):
                if item.get("rev", 0) >= have.get("rev", 0):
                    self.objects[i] = item
                return
        self.objects.append(item)

    def _bounded(self, table: OrderedDict, key: str) -> bool:
        if self._known is not None:
            return key in self._known
        if key not in table and len(table) >= MAX_KEYED:
            table.popitem(last=False)
        return True

    def _trim(self) -> None:
        if self.t is None:
            return
        horizon = self.t - self.tail
        while self.scans and len(self.scans) > 1 and self.scans[0]["t"] < horizon:
            self.scans.popleft()
        while self.truth and self.truth[0]["t"] < horizon:
            self.truth.popleft()

    def snapshot(self) -> Item:
        """Everything a page needs to draw the current picture at once."""
        return {"k": "snapshot", "t": self.t, "tail": self.tail, "deployment": self.deployment,
                "sensors": {sid: value for sid, value in self.sensors.items()},
                "scans": list(self.scans), "reports": self.reports, "estimates": list(self.estimates.values()),
                "objects": list(self.objects), "velocity": self.velocity, "truth": list(self.truth),
                "ended": self.ended}

    def size(self) -> dict[str, Any]:
        """How many entries each collection holds (for checks that the state stays bounded)."""
        return {"sensors": len(self.sensors), "scans": len(self.scans), "estimates": len(self.estimates),
                "objects": len(self.objects), "truth": len(self.truth)}
