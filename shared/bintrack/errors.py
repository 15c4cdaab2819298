"""The error a command raises for bad user input that is not a file-format fault."""


class CommandError(Exception):
    """A user-facing error: its text is one line; ``bintrack`` prints it and exits with status 2."""
