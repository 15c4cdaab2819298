"""The root of every error the library raises, and the error a command raises for bad user input.

Every error of bintrack subclasses :class:`BintrackError`, so a caller can catch them all at
once; each keeps the base its callers catch it by (``MessageError``, ``FormatError``,
``DegenerateError``, ``ScenarioError`` and ``TrackerConfigError`` are ``ValueError``s).
Algorithms raise their own errors, never :class:`CommandError`; the command line and the
services turn a :class:`TrackerConfigError` into the one-line exit-2 message of a command.
"""


class BintrackError(Exception):
    """Any error bintrack raises on purpose; its text is one line."""


class CommandError(BintrackError):
    """A user-facing error: its text is one line; ``bintrack`` prints it and exits with status 2."""


class TrackerConfigError(BintrackError, ValueError):
    """A tracker cannot run on this deployment or with these options (one line, naming the tracker).

    A ``ValueError``, as the options' other faults are: the callers that make a tracker turn
    either into a :class:`CommandError` with the same text."""
