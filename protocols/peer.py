"""Simulated byte-level peers and the registry ``sim://<name>`` looks them up in.

A peer speaks the real wire protocol: it receives exactly the bytes a host writes and returns
the bytes a real device would have sent by ``now_s``. It owns no clock; the transport passes the
current time on every call (``thrustmap.protocols.urlhandlers.protocol_sim.SimSerial``).

Peers are registered by ``thrustmap.rig.sim`` modules with ``register_peer``; when an unknown
name is requested, ``create_peer`` imports ``thrustmap.rig.sim.peers`` once (the module that
registers every built-in peer) before giving up with the list of known names.
"""

from __future__ import annotations

import importlib
import logging
from collections.abc import Callable, Mapping
from typing import Protocol, runtime_checkable

from thrustmap.errors import ConfigError

log = logging.getLogger(__name__)

PEERS_MODULE = "thrustmap.rig.sim.peers"


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
_peers_module_tried = False


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


def _load_builtin_peers() -> str | None:
    """Import the module that registers the built-in peers; return why it failed, if it did."""
    global _peers_module_tried
    if _peers_module_tried:
        return None
    _peers_module_tried = True
    try:
        importlib.import_module(PEERS_MODULE)
    except ModuleNotFoundError as exc:
        if exc.name is not None and PEERS_MODULE.startswith(exc.name):
            return f"{PEERS_MODULE} is not available"
        raise
    return None


def create_peer(name: str, options: Mapping[str, str] | None = None) -> BytePeer:
    key = name.lower()
    if key not in _REGISTRY:
        why = _load_builtin_peers()
        if why:
            log.debug("%s", why)
    factory = _REGISTRY.get(key)
    if factory is None:
        known = ", ".join(known_peers()) or "none registered"
        raise UnknownPeerError(
            f"unknown simulated peer {name!r} in sim://{name}; known peers: {known}"
        )
    return factory(dict(options or {}))
