"""A service started by a supervisor (``bintrack up``) ends when the supervisor does."""

from __future__ import annotations

import asyncio
import logging
import os
import signal
from collections.abc import Callable

PARENT_ENV = "BINTRACK_PARENT_PID"  # set by a supervisor (bintrack up): the service ends when that process does
PARENT_CHECK = 1.0  # s between checks that the supervisor is still there

log = logging.getLogger("bintrack")


def watch_parent(loop: asyncio.AbstractEventLoop, who: str, stop: Callable[[], None],
                 stopping: Callable[[], bool]) -> None:
    """End with the supervisor named by $BINTRACK_PARENT_PID (nothing if unset): the kernel sends
    SIGTERM when it dies (Linux), and a check every PARENT_CHECK s covers the rest (a service
    re-parented is an orphan)."""
    parent = os.environ.get(PARENT_ENV)
    if not parent:
        return
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass

    def check() -> None:
        if os.getppid() != int(parent):
            log.warning("%s: its supervisor (pid %s) is gone; stopping", who, parent)
            stop()
        elif not stopping():
            loop.call_later(PARENT_CHECK, check)

    check()
