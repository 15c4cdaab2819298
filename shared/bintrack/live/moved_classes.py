"""Where the classes a checkpoint names have moved, so that a checkpoint taken by an older
version still loads (a pickle names each class by module and name).

When a class a checkpoint can hold moves to another module (or is renamed), add its old home
here; tests/test_old_checkpoints.py loads a checkpoint taken before the last moves.
"""

from __future__ import annotations

import importlib
import pickle

MOVED: dict[str, tuple[str, ...]] = {
    # split by concept (one module each): the classes kept their names
    "bintrack.messages": ("bintrack.bus_payloads", "bintrack.deployment_model", "bintrack.message_base"),
    "bintrack.trackers.multi.mcmcda": ("bintrack.trackers.multi.mcmcda_config", "bintrack.trackers.multi.mcmcda_window"),
    "bintrack.trackers.laser.adaptive_basis": (
        "bintrack.trackers.laser.phase1_closed_form", "bintrack.trackers.laser.phase2_least_squares",
        "bintrack.trackers.laser.phase3_frame"),
    "bintrack.trackers.motion.closer_farther": ("bintrack.trackers.motion.svm_estimator",),
    "bintrack.trackers.multi.target_fit": ("bintrack.trackers.multi.track_expectation",),
}
"""old module -> the modules its classes went to"""

RENAMED: dict[tuple[str, str], tuple[str, str]] = {
    ("bintrack.messages", "_Model"): ("bintrack.message_base", "FrozenModel"),
    ("bintrack.trackers.multi.mcmcda", "_Report"): ("bintrack.trackers.multi.mcmcda_window", "WindowReport"),
    ("bintrack.trackers.multi.mcmcda", "_Gate"): ("bintrack.trackers.multi.mcmcda_window", "Gate"),
    ("bintrack.trackers.multi.mcmcda", "_Track"): ("bintrack.trackers.multi.mcmcda_window", "ChainTrack"),
}
"""(old module, old name) -> (module, name) of a class that was renamed as it moved"""


class CheckpointUnpickler(pickle.Unpickler):
    """An unpickler that finds a class at its new home when the checkpoint names its old one."""

    def find_class(self, module: str, name: str):
        if (module, name) in RENAMED:
            module, name = RENAMED[module, name]
        elif module in MOVED:
            try:
                return super().find_class(module, name)
            except (ImportError, AttributeError):
                for home in MOVED[module]:
                    found = getattr(importlib.import_module(home), name, None)
                    if isinstance(found, type):
                        return found
        return super().find_class(module, name)
