"""bintrack: tracking moving targets with networks of binary sensors.

By role (README, Layout): the contracts and the ground floor at the top (messages, keys,
formats, geometry, sensing, ordering, the transition detector, the pipeline), ``sim`` (the
simulator), ``trackers`` (one package per family), ``evaluation`` (metrics, reports, plots) —
all pure: no I/O but the file formats, no Zenoh — then ``live`` (the runtime on Zenoh) and
``cli`` (the command line). ``bintrack.client`` is the public client API.
"""

__version__ = "0.1.0"
