"""A service's checkpoint file: written atomically, readable only by its owner, and refused
when anybody else could have written it.

A checkpoint holds live Python objects (a tracker's state, a detector's), so it is a pickle,
and unpickling a file runs whatever code the file names. The defence is the one OpenSSH uses
for its keys: the file and its folder must belong to the user running the service and be
writable by nobody else; otherwise the checkpoint is refused with one line and the service
starts afresh. ``bintrack up`` keeps them in a private temporary folder (mode 0700).
"""

from __future__ import annotations

import os
import pickle
import stat


class CheckpointRefused(Exception):
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
    private to writes, or if it cannot be read back (truncated, from another version).
    """
    if not os.path.exists(path):
        return None
    reason = _unsafe(os.path.dirname(os.path.abspath(path))) or _unsafe(path)
    if reason:
        raise CheckpointRefused(f"not loaded: {reason}")
    try:
        with open(path, "rb") as handle:
            return pickle.load(handle)
    except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ImportError, ValueError) as exc:
        raise CheckpointRefused(f"unreadable ({type(exc).__name__}: {exc})") from exc


def save_checkpoint(path: str, state) -> None:
    """Write ``state`` to ``path`` atomically (aside, then renamed), mode 0600."""
    aside = path + ".tmp"
    fd = os.open(aside, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as handle:
        pickle.dump(state, handle, protocol=pickle.HIGHEST_PROTOCOL)
    os.replace(aside, path)
