"""Device URLs: their forms, and opening one as a non-blocking byte transport.

Device paths (``/dev/ttyACM0``, ``COM3``), ``socket://host:port``, thrustmap's ``sim://<peer>``,
``record://<url>?file=x.jsonl`` and ``replay://x.jsonl`` (pyserial URL handlers), and pymavlink
connection strings (``udpin:0.0.0.0:14550``, ``tcp:127.0.0.1:5760``).
"""

from __future__ import annotations

import importlib
import re
from typing import Any
from urllib.parse import unquote, urlsplit

from thrustmap.core.clock import Clock
from thrustmap.core.errors import ConfigError, ThrustmapError
from thrustmap.protocols.transport import SerialLike, open_transport

CLOCK_AWARE_SCHEMES = ("sim", "record", "replay")
#: pymavlink connection strings (SITL, companion computers, telemetry over IP)
MAVLINK_CONNECTION = re.compile(r"^(udpin|udpout|udp|udpbcast|tcp|tcpin):[^/]", re.IGNORECASE)
#: the module that registers the built-in simulated peers (``sim://betaflight`` ...)
SIM_PEERS_MODULE = "thrustmap.rig.sim.peers"


def url_scheme(url: str) -> str:
    head, sep, _ = url.partition("://")
    return head.lower() if sep and re.fullmatch(r"[A-Za-z][A-Za-z0-9+.-]*", head) else ""


def innermost_url(url: str) -> str:
    """Strip ``record://`` wrappers: ``record://sim://px4?file=x`` -> ``sim://px4``."""
    from thrustmap.protocols.urlhandlers.protocol_record import split_record_url

    seen = 0
    while url_scheme(url) == "record" and seen < 8:
        url, _ = split_record_url(url)
        seen += 1
    return url


def is_simulated(url: str) -> bool:
    """True when nothing real is behind ``url`` (``sim://``, ``replay://``, or those recorded)."""
    return url_scheme(innermost_url(url)) in ("sim", "replay")


def sim_peer(url: str) -> tuple[str, dict[str, str]] | None:
    """``sim://line-stand?preset=x`` -> ``("line-stand", {"preset": "x"})``; None otherwise."""
    inner = innermost_url(url)
    if url_scheme(inner) != "sim":
        return None
    from thrustmap.protocols.urlhandlers.protocol_sim import parse_query

    parts = urlsplit(inner)
    return unquote(parts.netloc or parts.path.lstrip("/")).lower(), parse_query(parts.query)


def _transport_kwargs(url: str, clock: Clock, baudrate: int | None) -> dict[str, Any]:
    kwargs: dict[str, Any] = {"timeout": 0}
    if url_scheme(url) in CLOCK_AWARE_SCHEMES:
        kwargs["clock"] = clock
    if baudrate is not None:
        kwargs["baudrate"] = baudrate
    return kwargs


def open_port(url: str, clock: Clock, *, baudrate: int | None = None) -> SerialLike:
    """Open ``url`` as a non-blocking byte transport (the clock reaches sim/record/replay).
    A port that cannot be opened (missing, busy, refused, unknown scheme) is a ``ConfigError``
    naming the URL."""
    if url_scheme(innermost_url(url)) == "sim":
        load_sim_peers()
    try:
        return open_transport(url, **_transport_kwargs(url, clock, baudrate))
    except ThrustmapError:
        raise
    except (OSError, ValueError) as exc:  # serial.SerialException is an OSError
        raise ConfigError(f"cannot open {url}: {exc}") from None


def load_sim_peers() -> None:
    """Register the built-in simulated peers (``sim://betaflight`` ...) with the transport; the
    protocols layer does not know the simulator, the rig tells it (idempotent)."""
    importlib.import_module(SIM_PEERS_MODULE)
