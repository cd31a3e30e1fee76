"""Simulated byte-level peers and the registry ``sim://<name>`` looks them up in.

A peer speaks the real wire protocol: it receives exactly the bytes a host writes and returns
the bytes a real device would have sent by ``now_s``. It owns no clock; the transport passes the
current time on every call (``thrustmap.protocols.urlhandlers.protocol_sim.SimSerial``).

Peers are registered with ``register_peer`` by whoever provides them (the simulator in
``thrustmap.rig.sim`` registers its built-in peers when the rig opens a ``sim://`` URL); this
layer knows nothing above it. An unknown name raises ``UnknownPeerError`` listing the known ones.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from typing import Protocol, runtime_checkable

from thrustmap.core.errors import ConfigError

log = logging.getLogger(__name__)


@runtime_checkable
class BytePeer(Protocol):
    """A simulated device at the byte level."""

    def write(self, data: bytes, now_s: float) -> None:
        """Bytes from the host arrive at ``now_s``."""
        ...

    def read(self, now_s: float) -> bytes:
        """Bytes the device has sent by ``now_s`` and the host has not yet taken."""
        ...


PeerFactory = Callable[[Mapping[str, str]], BytePeer]
"""Builds a peer from the URL options (``sim://px4?motors=4`` -> ``{"motors": "4"}``)."""

_REGISTRY: dict[str, PeerFactory] = {}


class UnknownPeerError(ConfigError):
    """``sim://<name>`` names no registered peer."""


def register_peer(name: str, factory: PeerFactory, *, replace: bool = False) -> None:
    """Make ``sim://<name>`` build a peer with ``factory``. Names are case-insensitive."""
    key = name.lower()
    if not key or not key.replace("-", "").replace("_", "").isalnum():
        raise ValueError(f"peer name must be letters, digits, '-' or '_': {name!r}")
    if key in _REGISTRY and not replace and _REGISTRY[key] is not factory:
        raise ValueError(f"peer {name!r} is already registered (pass replace=True to override)")
    _REGISTRY[key] = factory


def unregister_peer(name: str) -> None:
    _REGISTRY.pop(name.lower(), None)


def known_peers() -> list[str]:
    return sorted(_REGISTRY)


def create_peer(name: str, options: Mapping[str, str] | None = None) -> BytePeer:
    factory = _REGISTRY.get(name.lower())
    if factory is None:
        known = ", ".join(known_peers()) or "none registered"
        raise UnknownPeerError(
            f"unknown simulated peer {name!r} in sim://{name}; known peers: {known}"
        )
    return factory(dict(options or {}))
