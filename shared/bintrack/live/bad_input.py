"""A service's accounting of the bad payloads it refused, and the decoding that refuses them."""

from __future__ import annotations

import logging
from collections import defaultdict
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from bintrack.message_codec import MessageError, decode, decode_view

if TYPE_CHECKING:
    import zenoh

MAX_SENDERS_LOGGED = 1024  # distinct senders of bad payloads named in the log; past that only counted

log = logging.getLogger("bintrack")


@dataclass
class BadInput:
    """Bad payloads seen by a service: counted by reason (the first words, a bounded set),
    logged once per sender for the first MAX_SENDERS_LOGGED senders."""

    service: str
    counts: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    _logged: set[str] = field(default_factory=set)

    def report(self, sender: str, reason: str) -> None:
        kind = reason.split(":")[0]
        self.counts[kind] += 1
        if sender not in self._logged and len(self._logged) < MAX_SENDERS_LOGGED:
            self._logged.add(sender)
            if len(self._logged) == MAX_SENDERS_LOGGED:
                log.warning("%s: bad payloads from %d senders; further senders are only counted",
                            self.service, MAX_SENDERS_LOGGED)
            log.warning("%s: dropped a bad payload from %s: %s (further ones from it are only counted)",
                        self.service, sender, reason)

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def decode(self, cls: type, sample: zenoh.Sample, view: bool = False):
        """The ``cls`` message in ``sample``, or None (reported) if it is bad; with ``view``, a hot
        message comes as a read-only view (:func:`bintrack.message_codec.decode_view`)."""
        try:
            return (decode_view if view else decode)(cls, sample.payload.to_bytes())
        except MessageError as exc:
            self.report(str(sample.key_expr), exc.reason)
            return None
