"""bintrack: tracking moving targets with networks of binary sensors.

The library is pure (no I/O but the file formats, no Zenoh): messages, key expressions, file
formats, geometry, sensing models, the simulator, trackers and metrics.
"""

__version__ = "0.1.0"
