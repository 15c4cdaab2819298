"""The live runtime on Zenoh. A service (:mod:`~bintrack.live.service`) is composed of parts, one
concept a module: session options, the inbox, dispatch behind the control guard, presence,
progress reports, checkpoints, end of stream, the router and parent watches. Beside them: the
watermark, gap repair and transition intake of tracker services, replay's source, gate, player
and schedule, the recorder's filter and files, recordings, the client, the stack's service list,
the secure profile and the Foxglove export. Services (``bintrack.services``) wire these to the
trackers."""
