"""The deployment, fetched from replay's ``deployment`` queryable, with the run it names."""

from __future__ import annotations

import asyncio
import logging

import zenoh

from bintrack.deployment_model import Deployment
from bintrack.message_codec import MessageError, decode

RETRY = 0.05  # s between two asks while nobody answers (replay may still be starting)

log = logging.getLogger("bintrack")


def deployment_replies(session: zenoh.Session, key: str) -> list[tuple[bytes, str | None]]:
    """(payload, run id in its attachment or None) of each answer of the deployment queryable
    on ``key``; blocking (call off the loop)."""
    replies = session.get(key, timeout=1.0)
    return [(r.ok.payload.to_bytes(),
             None if r.ok.attachment is None else r.ok.attachment.to_bytes().decode(errors="replace"))
            for r in replies if r.ok is not None]


async def fetch_deployment(service) -> tuple[Deployment, str | None] | None:
    """(the deployment, its run id) from ``service``'s network, asked again until it answers;
    None if the service stops first. A bad answer is reported as bad input."""
    warned = False
    key = service.keys.deployment()
    while not service.stopping.is_set():
        for payload, run in await asyncio.to_thread(deployment_replies, service.session, key):
            try:
                return decode(Deployment, payload), run
            except MessageError as exc:
                service.bad.report(key, exc.reason)
        if not warned:
            log.info("%s: waiting for the deployment on %s", service.name, key)
            warned = True
        await asyncio.sleep(RETRY)
    return None
