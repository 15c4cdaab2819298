"""A service's checkpoint file: written atomically, readable only by its owner, and refused
when anybody else could have written it.

Each service keeps a dataclass of its own, named here so that every layout is in one place; a
:class:`Checkpointer` saves it with the run it belongs to and refuses one of another version.

A checkpoint holds live Python objects (a tracker's state, a detector's), so it is a pickle,
and unpickling a file runs whatever code the file names. The defence is the one OpenSSH uses
for its keys: the file and its folder must belong to the user running the service and be
writable by nobody else; otherwise the checkpoint is refused with one line and the service
starts afresh. ``bintrack up`` keeps them in a private temporary folder (mode 0700), in memory
where it can (:func:`memory_folder`).
"""

from __future__ import annotations

import io
import logging
import math
import os
import pickle
import stat
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from bintrack.errors import BintrackError
from bintrack.live.checkpoint_slots import MAGIC, SlotFile, is_slot_file, latest_payload
from bintrack.live.moved_classes import CheckpointUnpickler

if TYPE_CHECKING:
    from bintrack.live.gap_repair import IntakeState
    from bintrack.bus_payloads import TrackSet
    from bintrack.live.region_scan_counts import RegionScanCounts
    from bintrack.pipeline import TrackerDriver
    from bintrack.trackers.multi.region_merge import RegionMerge
    from bintrack.transition_detector import TransitionDetector

CHECKPOINT_INTERVAL = 1.0  # s of wall clock between two throttled checkpoints …
MEMORY_FOLDER = "/dev/shm"  # Linux's tmpfs for every user (sticky, like /tmp)
CHECKPOINT_SPAN = 8.0  # … or s of event time, whichever comes first (well inside the sensors' HISTORY_SPAN)
RESUME_MARGIN = 2.0  # s of event time more than resume_span's bound, for outputs that overtake one another

log = logging.getLogger("bintrack")


def resume_span(lead: float) -> float:
    """The event time (s) of its recent outputs a service keeps for a consumer restarted from its
    throttled checkpoint, when the clock sources may run ``lead`` s ahead of the acknowledgements.

    The checkpoint was taken at a tick up to CHECKPOINT_SPAN s before the consumer's last; what
    it had received by then lags that tick by up to ``lead`` (the upstream acknowledged only that
    far when the tick went out), and the upstream may be ``lead`` ahead of the consumer's last
    tick when both die."""
    return CHECKPOINT_SPAN + 2 * lead + RESUME_MARGIN


class CheckpointRefused(BintrackError):
    """The checkpoint exists but is not safe or not readable; the message says why in one line."""


def _unsafe(path: str) -> str | None:
    """Why ``path`` (a file or folder) could have been written by someone else, or None."""
    info = os.stat(path)
    if info.st_uid != os.getuid():
        return f"{path} belongs to uid {info.st_uid}, not to this user ({os.getuid()})"
    if info.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        return f"{path} is writable by group or others (mode {stat.S_IMODE(info.st_mode):o})"
    return None


def load_checkpoint(path: str):
    """The object saved at ``path``, or None if there is no file there.

    Raises :class:`CheckpointRefused` if the file or its folder is not the user's own and
    private to writes, or if it cannot be read back (cut short in both slots, from another
    version). It reads a slot file (:mod:`bintrack.live.checkpoint_slots`) or a plain pickle (a
    throttled checkpoint, or any of an earlier version). Classes
    that moved since the checkpoint was taken are found at their new homes
    (:mod:`bintrack.live.moved_classes`).
    """
    if not os.path.exists(path):
        return None
    reason = _unsafe(os.path.dirname(os.path.abspath(path))) or _unsafe(path)
    if reason:
        raise CheckpointRefused(f"not loaded: {reason}")
    try:
        with open(path, "rb") as handle:
            if not is_slot_file(handle.read(len(MAGIC))):  # a new file's pickle: read as it streams
                handle.seek(0)
                return CheckpointUnpickler(handle).load()
            handle.seek(0)
            return CheckpointUnpickler(io.BytesIO(latest_payload(handle.read()))).load()
    except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ImportError, ValueError) as exc:
        raise CheckpointRefused(f"unreadable ({type(exc).__name__}: {exc})") from exc


def memory_folder() -> str | None:
    """Where a stack's private state folder goes: in memory (tmpfs) if this machine has one
    open to this user, else None (the system's temporary folder). Sensor agents and replay save
    a checkpoint at every clock tick (:mod:`bintrack.live.checkpoint_slots`); in memory those
    writes never reach a disk."""
    return MEMORY_FOLDER if os.path.isdir(MEMORY_FOLDER) and os.access(MEMORY_FOLDER, os.W_OK | os.X_OK) else None


def save_checkpoint(path: str, state) -> None:
    """Write ``state`` to a new file at ``path`` atomically (aside, then renamed), mode 0600,
    pickled straight into it (a tracker's state is megabytes: no copy in memory)."""
    aside = path + ".tmp"
    fd = os.open(aside, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as handle:
        pickle.dump(state, handle, protocol=pickle.HIGHEST_PROTOCOL)
    os.replace(aside, path)


@dataclass
class IntakeCheckpoint:
    """A transition consumer's checkpoint, taken after a clock tick's outputs went out."""

    tick: float  # s: the clock tick it was taken at
    driver: TrackerDriver
    intake: IntakeState
    extra: Any = None  # what the service adds (:meth:`TransitionConsumer.checkpoint_extra`)



@dataclass
class ReplayCheckpoint:
    """Where replay was: the last tick it published (s) and how many samples it had published."""

    tick: float
    published: int



@dataclass
class SensorAgentCheckpoint:
    """A sensor agent's checkpoint, taken at a clock tick it acknowledged."""

    tick: float  # s
    sent: int  # transitions sent so far
    detector: TransitionDetector | None
    sensors: dict[str, float]  # hosted sensor → event time of its last sample, s
    # the transitions sent in the last resume_span s, encoded as sent (an earlier version's:
    # (schema version, *Sent) tuples)
    recent: list[bytes | tuple] = field(default_factory=list)
    sent_to: dict[str, int] | None = None  # with regions: of ``sent``, those of each region's sensors (DESIGN §11)



@dataclass
class MergeCheckpoint:
    """The merge's checkpoint: its state and the track sets it served."""

    merge: RegionMerge
    latest: TrackSet | None
    history: list[TrackSet]
    counts: RegionScanCounts | None = None  # None in a checkpoint from before the scans were counted



@dataclass
class BridgeCheckpoint:
    """The MQTT bridge's: its core's state (:meth:`bintrack.mqtt.bridge_core.BridgeCore.snapshot`),
    taken after a tick it published; its journal holds the messages taken since."""

    core: dict


@dataclass
class RelayCheckpoint:
    """The estimate relay's, taken at a clock tick: the estimates not released yet (a
    ReorderBuffer, which knows how far it released), the payloads seen per node, and the track
    sets it served (the latest and the recent ones)."""

    tick: float
    estimates: Any
    recent: dict[str, list[bytes]]
    latest: TrackSet | None
    history: list[TrackSet]


@dataclass
class RecorderCheckpoint:
    """Which split part the recorder was writing."""

    part: int


class Checkpointer:
    """One service instance's checkpoint: ``<state dir>/<service>-<id>.pickle`` (none without a
    state dir), tagged with the run it belongs to.

    A run is replay's: it names it in its answers on ``deployment``, and a service that asked
    for the deployment first (every one but replay) keeps only a checkpoint of the same run, so
    a stack started afresh on an old state folder (a compose volume) does not resume what
    another run left. Replay resumes its own run. Each service saves a dataclass of its own;
    a checkpoint holding anything else is of another version and refused.
    """

    def __init__(self, folder: str | None, service: str, instance: str):
        self.service = service
        self.instance = instance
        self.path = None if not folder else os.path.join(folder, f"{service}-{instance}.pickle")
        self.slots = None if self.path is None else SlotFile(self.path)  # made at the first save
        self.run_id: str | None = None  # the run this instance belongs to (replay's)
        self._saved_at = -math.inf  # monotonic time of the last throttled checkpoint
        self._saved_t = -math.inf  # event time (s) it was taken at

    def load(self, kind: type):
        """The ``kind`` saved by :meth:`save` before a restart, or None: none saved, or refused
        (logged; the service starts afresh) because it is unsafe or damaged, of another version
        or of an earlier run."""
        if self.path is None:
            return None
        try:
            saved = load_checkpoint(self.path)
        except CheckpointRefused as exc:
            log.warning("%s: checkpoint %s %s; starting afresh", self.service, self.path, exc)
            return None
        if saved is None:
            return None
        if not isinstance(saved, dict) or set(saved) != {"run", "state"} or not isinstance(saved["state"], kind):
            log.warning("%s: checkpoint %s is not of this version; starting afresh", self.service, self.path)
            return None
        if self.run_id is not None and saved["run"] != self.run_id:
            log.warning("%s: checkpoint %s is of another run (%s; replay's is %s); starting afresh",
                        self.service, self.path, saved["run"], self.run_id)
            return None
        self.run_id = saved["run"]
        log.info("%s %s: restarted; resuming from its checkpoint", self.service, self.instance)
        return saved["state"]

    def save(self, state: Any) -> None:
        """Save ``state`` with the run it belongs to, atomically and private to this user, if
        there is a state dir: a small state saved often (at every tick), into a slot of the file
        kept open (:mod:`bintrack.live.checkpoint_slots`)."""
        if self.slots is not None:
            self.slots.write(pickle.dumps({"run": self.run_id, "state": state}, protocol=pickle.HIGHEST_PROTOCOL))

    def save_throttled(self, t: float, state: Callable[[], Any]) -> None:
        """Save ``state()`` at event time ``t`` (s) if CHECKPOINT_INTERVAL s of wall clock or
        CHECKPOINT_SPAN s of event time passed since the last one: for a state that takes long to
        save (a tracker's), whose outputs a restarted instance sends again and the receivers
        drop as duplicates. It is pickled straight into a new file (:func:`save_checkpoint`)."""
        now = time.monotonic()
        if self.path is not None and (now - self._saved_at >= CHECKPOINT_INTERVAL
                                      or t - self._saved_t >= CHECKPOINT_SPAN):
            self.slots.close()  # the file is replaced: the next save makes a slot file afresh
            save_checkpoint(self.path, {"run": self.run_id, "state": state()})
            self._saved_at, self._saved_t = now, t
