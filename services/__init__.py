"""The processes on the bus (importable as ``bintrack.services``): wiring only, no algorithms."""
