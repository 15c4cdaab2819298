"""The live runtime on Zenoh: the bus (sessions, bounded inboxes, services), the ordered
transition intake with its sequence checks, recordings, the client, the stack's service list and
replay's schedule. Services (``bintrack.services``) wire these to the trackers."""
