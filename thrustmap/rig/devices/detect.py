"""What is on the other end of a URL: from the URL itself, or by a safe probe of the port.

``sim://`` URLs say it in the peer name, ``replay://`` transcripts in their header (or in the
first bytes the host wrote). A real port is probed safely: first it is only listened to (each
registered driver's ``classify``: MAVLink HEARTBEATs, the Tyto ``Ready`` banner, a line stand's
``#COLS`` header or CSV lines), and only then is ONE whole MSP frame written (API_VERSION;
FC_VARIANT when it answers). Nothing else is ever written: a stray ``R`` can reboot a Betaflight
FC into its bootloader, a ``#`` drops it into its CLI.
"""

from __future__ import annotations

import logging
import re
from urllib.parse import unquote, urlsplit

from thrustmap.core.clock import Clock
from thrustmap.core.errors import ConfigError, ThrustmapError
from thrustmap.protocols.msp.framing import MspDecoder, MspDirection, encode_request
from thrustmap.protocols.msp.messages import ApiVersion, FcVariant, MspCommand
from thrustmap.protocols.transport import SerialLike
from thrustmap.rig.devices.registry import Detection, drivers, normalize_kind
from thrustmap.rig.devices.urls import (
    MAVLINK_CONNECTION,
    innermost_url,
    open_port,
    sim_peer,
    url_scheme,
)

log = logging.getLogger(__name__)

#: baud rates a real port is probed at when none is given (USB CDC ignores the rate, so the
#: first pass finds FCs and most USB stands; 250000 is the Tyto, 921600 the STM32 stand)
PROBE_BAUDS = (115200, 250000, 921600)


def detect_from_url(url: str) -> Detection | None:
    """The kind a URL names without any I/O on a device (sim peers, replay transcripts,
    pymavlink connection strings such as ``udpin:0.0.0.0:14550``)."""
    inner = innermost_url(url)  # also recorded: record://udpin:0.0.0.0:14550?file=x.jsonl
    if MAVLINK_CONNECTION.match(inner) or url_scheme(inner) in ("udpin", "udpout", "tcpin"):
        return Detection("mavlink", evidence="pymavlink connection string")
    for drv in drivers():
        if url_scheme(inner) in drv.url_schemes:
            return Detection(drv.kind, evidence=f"{url_scheme(inner)}:// URL")
    peer = sim_peer(url)
    if peer is not None:
        name, options = peer
        for drv in drivers():
            found = drv.sim_detect(name, options)
            if found is not None:
                return found
        return None
    inner = innermost_url(url)
    if url_scheme(inner) == "replay":
        return _detect_from_transcript(inner)
    return None


def _detect_from_transcript(url: str) -> Detection | None:
    from thrustmap.protocols.transcript import read_transcript

    path = unquote(urlsplit(url).netloc + urlsplit(url).path) if "://" in url else url
    try:
        transcript = read_transcript(path)
    except (ThrustmapError, OSError) as exc:
        log.debug("cannot read transcript %s for detection: %s", path, exc)
        return None
    recorded = transcript.header.inner
    # the header's URL only describes what was recorded: never open what a file names
    if recorded and url_scheme(innermost_url(recorded)) == "sim":
        found = detect_from_url(recorded)
        if found is not None:
            return Detection(
                found.kind, found.firmware, found.line_preset, f"transcript of {recorded}"
            )
    found = classify_bytes(transcript.read())
    if found is not None:
        return found
    written = transcript.written()
    for drv in drivers():
        if drv.host_prefixes and written.startswith(drv.host_prefixes):
            return Detection(drv.kind, evidence=f"transcript: the host wrote {drv.description}")
    return None


def classify_bytes(data: bytes) -> Detection | None:
    """Recognise a device from bytes it sent unasked (no writes involved): each registered
    driver's ``classify`` in turn."""
    text = data.decode("latin-1")
    lines = [ln.strip() for ln in re.split(r"[\r\n]+", text)]
    complete = lines[:-1]  # the last piece may be cut short
    for drv in drivers():
        if drv.classify is not None:
            found = drv.classify(data, complete)
            if found is not None:
                return found
    return None


def sniff(
    port: SerialLike,
    clock: Clock,
    *,
    listen_s: float = 2.0,
    msp_timeout_s: float = 1.5,
    send_msp: bool = True,
    heard: bytearray | None = None,
) -> Detection | None:
    """Listen for ``listen_s``, then (if nothing spoke) ask once for MSP API_VERSION, waiting
    as long as the MSP driver's longest wait (a SITL on a busy machine, a radio bridge)."""
    port.timeout = 0.0
    seen = bytearray()
    deadline = clock.now_s() + listen_s
    while True:
        data = port.read(max(1, port.in_waiting))
        if data:
            seen += data
            del seen[: max(0, len(seen) - 65536)]
            found = classify_bytes(bytes(seen))
            if found is not None:
                return found
        elif clock.now_s() >= deadline:
            break
        else:
            clock.sleep_s(0.01)
    if heard is not None:
        heard += seen[: 4096 - len(heard)]
    if not send_msp:
        return None
    api = _msp_ask(port, clock, MspCommand.API_VERSION, msp_timeout_s)
    if api is None:
        return None
    try:
        version = ApiVersion.decode(api)
        evidence = f"MSP API {version.major}.{version.minor}"
    except ThrustmapError:
        evidence = "MSP reply"
    firmware = None
    variant = _msp_ask(port, clock, MspCommand.FC_VARIANT, msp_timeout_s)
    if variant is not None:
        try:
            ident = FcVariant.decode(variant).identifier
            firmware = {"BTFL": "betaflight", "INAV": "inav"}.get(ident, ident.lower())
        except ThrustmapError:
            pass
    return Detection("msp", firmware, evidence=evidence)


def _msp_ask(port: SerialLike, clock: Clock, cmd: int, timeout_s: float) -> bytes | None:
    decoder = MspDecoder()
    port.write(encode_request(cmd))  # one whole frame, nothing else
    deadline = clock.now_s() + timeout_s
    while True:
        data = port.read(max(1, port.in_waiting))
        for frame in decoder.feed(data):
            if frame.cmd == cmd and frame.direction is not MspDirection.REQUEST:
                return None if frame.is_error else frame.payload
        if clock.now_s() >= deadline:
            return None
        if not data:
            clock.sleep_s(0.002)


def detect_kind(
    url: str,
    clock: Clock,
    *,
    baudrate: int | None = None,
    listen_s: float = 2.0,
) -> Detection:
    """What ``url`` is: from the URL itself, else by a safe probe of the port (see module)."""
    found = detect_from_url(url)
    if found is not None:
        return found
    if url_scheme(innermost_url(url)) == "replay":
        raise ConfigError(
            f"cannot tell what the transcript {url} recorded; pass --kind "
            f"({', '.join(d.kind for d in drivers())})"
        )
    bauds = (baudrate,) if baudrate is not None else PROBE_BAUDS
    heard: dict[int, bytearray] = {}
    for i, baud in enumerate(bauds):
        port = open_port(url, clock, baudrate=baud)
        heard[baud] = bytearray()
        try:
            log.info("probing %s at %d baud", url, baud)
            # MSP is asked only on the first pass: FCs answer at any rate over USB.
            found = sniff(port, clock, listen_s=listen_s, send_msp=(i == 0), heard=heard[baud])
        finally:
            port.close()
        if found is not None:
            log.info("%s: %s (%s)", url, found.kind, found.evidence)
            return found
    tried = ", ".join(str(b) for b in bauds)
    raise ConfigError(
        f"could not tell what is on {url} (listened at {tried} baud, asked MSP API_VERSION); "
        f"{heard_summary(heard)}; pass --kind and --baud"
    )


def heard_summary(heard: dict[int, bytearray]) -> str:
    """What a port printed while it was listened to (its first lines), or that it was silent
    and which presets' firmware waits silently for a start command probe never sends."""
    for baud, data in heard.items():
        lines = [ln.strip() for ln in re.split(r"[\r\n]+", data.decode("latin-1")) if ln.strip()]
        if lines:
            shown = " | ".join(repr(ln[:60]) for ln in lines[:3])
            return f"at {baud} baud it printed {shown}, which no preset knows"
    from thrustmap.protocols.stands.line_presets import presets

    silent = [
        f"{s.name} (waits for {s.sequence_start.strip()!r}, which starts its sweep)"
        for s in presets().values()
        if s.sequence_start is not None
    ]
    waits = f"; stands silent until asked: {', '.join(silent)}" if silent else ""
    return "it printed nothing" + waits


def resolve(url: str, clock: Clock, kind: str | None, baudrate: int | None) -> Detection:
    if kind is None:
        return detect_kind(url, clock, baudrate=baudrate)
    base, firmware = normalize_kind(kind)
    found = detect_from_url(url)
    preset_name = found.line_preset if found is not None and found.kind == base else None
    if found is not None and firmware is None and found.kind == base:
        firmware = found.firmware
    return Detection(base, firmware, preset_name, evidence="--kind")
