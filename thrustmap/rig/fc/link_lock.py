"""The locked link, seen from a driver: who sent to a network endpoint besides its peer.

The transports (``protocols.urlhandlers.protocol_udpin``, ``protocol_tcpin``) lock onto one
peer and drop, count and name everything else; ``IntruderWatch`` turns that count into
``LinkIntruder`` while motors are commanded (the run then stops the motor through the locked
peer and aborts, exit 1) and into one log warning otherwise. MAVLink (``mavlink_session``) and
MSP (``msp``) drivers use it alike.
"""

from __future__ import annotations

import logging
from typing import Any

from thrustmap.core.errors import SafetyError
from thrustmap.protocols.transport import locked_endpoint

log = logging.getLogger(__name__)


class LinkIntruder(SafetyError):
    """Another address sent to the locked link while motors were commanded."""


class IntruderWatch:
    """Watch the locked endpoint under ``transport`` (if it has one)."""

    def __init__(self, transport: Any) -> None:
        self.endpoint = locked_endpoint(transport)
        self._reported = 0

    @property
    def peer(self) -> str | None:
        return getattr(self.endpoint, "peer", None)

    def check_claims(self, *, peer_label: str | None = None) -> None:
        """Raise ``LinkIntruder`` if another address sent what would have identified the peer
        (a second vehicle HEARTBEAT): which one is the vehicle is then unknown, and no command
        may go out (a spoofer that spoke first holds the lock)."""
        endpoint = self.endpoint
        if endpoint is None or not int(getattr(endpoint, "foreign_claims", 0)):
            return
        claim = endpoint.last_claim
        raise LinkIntruder(
            f"{claim[0]}:{claim[1]} also claims to be the vehicle (the link is locked to "
            f"{peer_label or self.peer}): two vehicles, or a spoofer, on one port; no command "
            "sent (name the vehicle's address: udpout:HOST:PORT or tcp:HOST:PORT, or sign)"
        )

    def check(
        self, *, commanded: bool, starting: bool = False, peer_label: str | None = None
    ) -> None:
        """Raise ``LinkIntruder`` if anything from another address arrived and a motor is
        ``commanded`` (``starting``: about to be, nothing sent yet); otherwise log it once per
        new arrival."""
        endpoint = self.endpoint
        count = 0 if endpoint is None else int(endpoint.intrusions)
        if count == 0:
            return
        label = peer_label or self.peer or "its peer"
        if commanded:
            last = endpoint.last_foreign
            names = ", ".join(f"{h}:{p} ({n})" for (h, p), n in endpoint.foreign_senders.items())
            what = (
                "before a motor command (the link is locked to {label}): no motor command sent"
                if starting
                else "while a motor was commanded (the link is locked to {label}): run "
                "aborted, the stop goes to the locked peer only"
            ).format(label=label)
            raise LinkIntruder(
                f"{last[0]}:{last[1]} sent to the vehicle link {what}; {count} "
                f"datagram(s)/connection(s) dropped, none answered (from {names})"
            )
        if count > self._reported:
            self._reported = count
            log.warning(
                "%d datagram(s)/connection(s) from other addresses dropped (locked to %s)",
                count,
                label,
            )
