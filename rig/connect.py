"""Open devices by URL: the factories the CLI (``probe``, ``spin``, ``sweep``) builds on.

- ``open_throttle_output(url, clock, kind=...)``: an FC over MSP (Betaflight/INAV) or MAVLink
  (PX4/ArduPilot), or a stand's own ESC output (Tyto 1585, line stand).
- ``open_stand(url, clock, kind=...)``: a Tyto 1585 (needs its calibration file) or a line stand
  (a preset or a JSON spec file).
- ``detect_kind(url, clock)``: what is on the other end. ``sim://`` URLs say it in the peer name,
  ``replay://`` transcripts in their header (or in the first bytes the host wrote). A real port
  is probed safely: first it is only listened to (MAVLink HEARTBEATs, the Tyto ``Ready`` banner,
  a line stand's ``#COLS`` header or CSV lines), and only then is ONE whole MSP frame written
  (API_VERSION; FC_VARIANT when it answers). Nothing else is ever written: a stray ``R`` can
  reboot a Betaflight FC into its bootloader, a ``#`` drops it into its CLI.
- ``describe_port(port_info)``: a guess at what a serial port is from its USB VID/PID and
  strings, without opening it (``thrustmap ports``).
- ``probe_device(url, clock)``: identity plus a short live reading (``thrustmap probe``).

Kinds: ``msp`` (aliases ``betaflight``, ``inav``), ``mavlink`` (``px4``, ``ardupilot``: also the
autopilot hint), ``tyto-1585`` (``tyto``), ``line-stand`` (``line``).
"""

from __future__ import annotations

import importlib
import logging
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol
from urllib.parse import unquote, urlsplit

from thrustmap.clock import Clock
from thrustmap.errors import ConfigError, SafetyError, ThrustmapError
from thrustmap.protocols.mavlink.codec import MavlinkCodec, decode_heartbeat
from thrustmap.protocols.msp.framing import MspDecoder, MspDirection, encode_request
from thrustmap.protocols.msp.messages import ApiVersion, FcVariant, MspCommand
from thrustmap.protocols.stands.line import PRESETS, LineStandSpec, preset
from thrustmap.protocols.stands.tyto import TYTO_READY_LINE, TytoCalibration
from thrustmap.protocols.transport import SerialLike, open_transport
from thrustmap.rig.interfaces import (
    DeviceIdentity,
    Stand,
    StandSample,
    Telemetry,
    ThrottleOutput,
)
from thrustmap.rig.stand.line import LineStand, LineStandEscOutput, load_line_spec

log = logging.getLogger(__name__)

FC_KINDS = ("msp", "mavlink")
STAND_KINDS = ("tyto-1585", "line-stand")
KINDS = FC_KINDS + STAND_KINDS
KIND_ALIASES: dict[str, tuple[str, str | None]] = {
    "msp": ("msp", None),
    "betaflight": ("msp", "betaflight"),
    "inav": ("msp", "inav"),
    "mavlink": ("mavlink", None),
    "px4": ("mavlink", "px4"),
    "ardupilot": ("mavlink", "ardupilot"),
    "tyto": ("tyto-1585", None),
    "tyto-1585": ("tyto-1585", None),
    "line": ("line-stand", None),
    "line-stand": ("line-stand", None),
}
DEFAULT_BAUD = {"msp": 115200, "mavlink": 115200, "tyto-1585": 250000, "line-stand": 115200}
#: baud rates a real port is probed at when none is given (USB CDC ignores the rate, so the
#: first pass finds FCs and most USB stands; 250000 is the Tyto, 921600 the STM32 stand)
PROBE_BAUDS = (115200, 250000, 921600)
CLOCK_AWARE_SCHEMES = ("sim", "record", "replay")
#: pymavlink connection strings (SITL, companion computers, telemetry over IP)
MAVLINK_CONNECTION = re.compile(r"^(udpin|udpout|udp|udpbcast|tcp|tcpin):[^/]", re.IGNORECASE)


def normalize_kind(kind: str) -> tuple[str, str | None]:
    """``"betaflight"`` -> ``("msp", "betaflight")``; unknown kinds raise ``ConfigError``."""
    try:
        return KIND_ALIASES[kind.strip().lower()]
    except KeyError:
        raise ConfigError(
            f"unknown device kind '{kind}'; expected one of: {', '.join(KIND_ALIASES)}"
        ) from None


# --------------------------------------------------------------------------- URLs


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
    """Open ``url`` as a non-blocking byte transport (the clock reaches sim/record/replay)."""
    return open_transport(url, **_transport_kwargs(url, clock, baudrate))


# --------------------------------------------------------------------------- detection


@dataclass(frozen=True)
class Detection:
    """What a URL or a port turned out to be."""

    kind: str  # one of KINDS
    firmware: str | None = None  # "betaflight", "inav", "px4", "ardupilot", ...
    line_preset: str | None = None  # for line stands, when the header matches a preset
    evidence: str = ""


_SIM_KINDS: dict[str, tuple[str, str | None]] = {
    "betaflight": ("msp", "betaflight"),
    "inav": ("msp", "inav"),
    "px4": ("mavlink", "px4"),
    "ardupilot": ("mavlink", "ardupilot"),
    "tyto-1585": ("tyto-1585", None),
    "line-stand": ("line-stand", None),
}


def _sim_line_preset(options: Mapping[str, str]) -> str:
    """The line preset a ``sim://line-stand`` URL asks for (``line_preset=`` or ``preset=``)."""
    for key in ("line_preset", "preset"):
        if options.get(key, "").lower() in PRESETS:
            return options[key].lower()
    return "thrustmap-line"


def detect_from_url(url: str) -> Detection | None:
    """The kind a URL names without any I/O on a device (sim peers, replay transcripts,
    pymavlink connection strings such as ``udpin:0.0.0.0:14550``)."""
    if MAVLINK_CONNECTION.match(url):
        return Detection("mavlink", evidence="pymavlink connection string")
    peer = sim_peer(url)
    if peer is not None:
        name, options = peer
        if name in _SIM_KINDS:
            kind, firmware = _SIM_KINDS[name]
            if name == "inav" or options.get("firmware", "").startswith("inav"):
                firmware = "inav" if kind == "msp" else firmware
            line = _sim_line_preset(options) if kind == "line-stand" else None
            return Detection(kind, firmware, line, f"simulated peer sim://{name}")
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
    found = classify_bytes(transcript.read(), MavlinkCodec())
    if found is not None:
        return found
    written = transcript.written()
    if written.startswith((b"$M<", b"$X<")):
        return Detection("msp", evidence="transcript: the host wrote MSP")
    if written[:1] in (b"\xfd", b"\xfe"):
        return Detection("mavlink", evidence="transcript: the host wrote MAVLink")
    if written.startswith(b"$R<"):
        return Detection("tyto-1585", evidence="transcript: the host wrote Tyto polls")
    return None


def _header_preset(names: Sequence[str]) -> str | None:
    lower = {n.lower() for n in names}
    for spec in PRESETS.values():
        named = [c.name.lower() for c in spec.columns.values() if c.name is not None]
        if named and all(n in lower for n in named) and spec.header_names:
            return spec.name
    return None


_NUMBER = re.compile(r"^[-+]?(\d+(\.\d*)?|\.\d+)([eE][-+]?\d+)?$")


def classify_bytes(data: bytes, codec: MavlinkCodec) -> Detection | None:
    """Recognise a device from bytes it sent unasked (no writes involved)."""
    for msg in codec.feed(data):
        if msg.get_type() == "HEARTBEAT":
            hb = decode_heartbeat(msg)
            if hb.is_vehicle:
                firmware = hb.firmware if hb.firmware != "other" else None
                return Detection(
                    "mavlink", firmware, evidence=f"MAVLink HEARTBEAT (autopilot {hb.autopilot})"
                )
    text = data.decode("latin-1")
    lines = [ln.strip() for ln in re.split(r"[\r\n]+", text)]
    complete = lines[:-1]  # the last piece may be cut short
    if TYTO_READY_LINE in complete:
        return Detection("tyto-1585", evidence=f"'{TYTO_READY_LINE}' banner")
    for line in complete:
        if line.startswith("#COLS"):
            names = [n for n in re.split(r"[,\s;]+", line[len("#COLS") :].strip()) if n]
            return Detection(
                "line-stand", line_preset=_header_preset(names), evidence=f"header '{line[:60]}'"
            )
    numeric = 0
    widths: set[int] = set()
    for line in complete:
        cells = [c for c in re.split(r"[,;\s]+", line) if c]
        if len(cells) >= 2 and all(_NUMBER.match(c) for c in cells):
            numeric += 1
            widths.add(len(cells))
    if numeric >= 3 and len(widths) == 1:
        width = widths.pop()
        guess = "stm32-hx711" if width == 3 else None
        return Detection(
            "line-stand", line_preset=guess, evidence=f"{numeric} numeric lines of {width} fields"
        )
    return None


def sniff(
    port: SerialLike,
    clock: Clock,
    *,
    listen_s: float = 2.0,
    msp_timeout_s: float = 0.5,
    send_msp: bool = True,
) -> Detection | None:
    """Listen for ``listen_s``, then (if nothing spoke) ask once for MSP API_VERSION."""
    port.timeout = 0.0
    codec = MavlinkCodec()
    seen = bytearray()
    deadline = clock.now_s() + listen_s
    while True:
        data = port.read(max(1, port.in_waiting))
        if data:
            seen += data
            del seen[: max(0, len(seen) - 65536)]
            found = classify_bytes(bytes(seen), MavlinkCodec())
            codec.feed(data)
            if found is not None:
                return found
        elif clock.now_s() >= deadline:
            break
        else:
            clock.sleep_s(0.01)
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
            f"cannot tell what the transcript {url} recorded; pass --kind (msp, mavlink, "
            "tyto-1585, line-stand)"
        )
    bauds = (baudrate,) if baudrate is not None else PROBE_BAUDS
    for i, baud in enumerate(bauds):
        try:
            port = open_port(url, clock, baudrate=baud)
        except (OSError, ValueError) as exc:
            raise ConfigError(f"cannot open {url}: {exc}") from None
        try:
            log.info("probing %s at %d baud", url, baud)
            # MSP is asked only on the first pass: FCs answer at any rate over USB.
            found = sniff(port, clock, listen_s=listen_s, send_msp=(i == 0))
        finally:
            port.close()
        if found is not None:
            log.info("%s: %s (%s)", url, found.kind, found.evidence)
            return found
    tried = ", ".join(str(b) for b in bauds)
    raise ConfigError(
        f"could not tell what is on {url} (listened at {tried} baud, asked MSP API_VERSION); "
        "pass --kind and --baud"
    )


def _resolve(url: str, clock: Clock, kind: str | None, baudrate: int | None) -> Detection:
    if kind is None:
        return detect_kind(url, clock, baudrate=baudrate)
    base, firmware = normalize_kind(kind)
    found = detect_from_url(url)
    preset_name = found.line_preset if found is not None and found.kind == base else None
    if found is not None and firmware is None and found.kind == base:
        firmware = found.firmware
    return Detection(base, firmware, preset_name, evidence="--kind")


# --------------------------------------------------------------------------- factories


class StandEscOutput(ThrottleOutput):
    """A stand's ESC output that owns its stand: closing it closes the stand (and its port)."""

    def __init__(self, inner: ThrottleOutput, stand: Stand) -> None:
        self.inner = inner
        self.stand = stand
        self.throttle_scale = inner.throttle_scale

    def identify(self) -> DeviceIdentity:
        return self.inner.identify()

    def set_throttle(self, values: Mapping[int, float]) -> None:
        self.inner.set_throttle(values)

    def keepalive(self) -> None:
        self.inner.keepalive()

    def stop(self) -> None:
        self.inner.stop()

    def verify_stopped(self) -> bool:
        return self.inner.verify_stopped()

    def stop_and_verify(self, attempts: int = 3) -> bool:
        return self.inner.stop_and_verify(attempts)

    def read_telemetry(self) -> Telemetry:
        return self.inner.read_telemetry()

    def close(self) -> None:
        try:
            self.inner.close()
        finally:
            self.stand.close()


def stand_esc_output(stand: Stand, motor: int = 0) -> ThrottleOutput:
    """The ESC output of a stand that drives its ESC (Tyto 1585, a line stand with a throttle
    command). The stand keeps its port: close the stand, not this output."""
    from thrustmap.rig.stand.tyto import TytoEscOutput, TytoStand

    if isinstance(stand, TytoStand):
        return TytoEscOutput(stand, motor)
    if isinstance(stand, LineStand):
        return LineStandEscOutput(stand, motor)
    raise ConfigError(f"a {type(stand).__name__} cannot drive an ESC")


def open_throttle_output(
    url: str,
    clock: Clock,
    *,
    kind: str | None = None,
    baudrate: int | None = None,
    motor: int = 0,
    calibration: str | None = None,
    line_preset: str | None = None,
    line_spec_file: str | None = None,
    **opts: Any,
) -> ThrottleOutput:
    """Open whatever commands motor throttle at ``url``.

    ``kind`` (see module) is detected when None. ``opts`` go to the driver's constructor
    (``MspThrottleOutput(timeout_s=, retries=)``) or to ``open_mavlink_output``. For a stand's
    own ESC output (``tyto-1585``, ``line-stand``) ``motor`` is the motor it drives and the
    returned output owns the stand (``.stand``; closing the output closes it).
    """
    found = _resolve(url, clock, kind, baudrate)
    if found.kind == "msp":
        from thrustmap.rig.fc.msp import MspThrottleOutput

        port = open_port(url, clock, baudrate=baudrate or DEFAULT_BAUD["msp"])
        try:
            return MspThrottleOutput(port, clock, **opts)
        except BaseException:
            port.close()
            raise
    if found.kind == "mavlink":
        return _open_mavlink(url, clock, found.firmware, baudrate, opts)
    stand = open_stand(
        url,
        clock,
        kind=found.kind,
        calibration=calibration,
        line_preset=line_preset or found.line_preset,
        line_spec_file=line_spec_file,
        baudrate=baudrate,
    )
    try:
        return StandEscOutput(stand_esc_output(stand, motor), stand)
    except BaseException:
        stand.close()
        raise


def _open_mavlink(
    url: str,
    clock: Clock,
    autopilot: str | None,
    baudrate: int | None,
    opts: Mapping[str, Any],
) -> ThrottleOutput:
    try:
        module = importlib.import_module("thrustmap.rig.fc.mavlink")
    except ModuleNotFoundError as exc:
        if exc.name is not None and exc.name.startswith("thrustmap.rig"):
            raise ConfigError(
                "MAVLink flight controllers (PX4/ArduPilot) need thrustmap.rig.fc.mavlink, "
                "which this build does not have"
            ) from None
        raise
    factory = getattr(module, "open_mavlink_output", None)
    if factory is None:
        raise ConfigError("thrustmap.rig.fc.mavlink has no open_mavlink_output()")
    from thrustmap.protocols.mavlink.link import (
        GCS_COMPONENT_ID,
        GCS_SYSTEM_ID,
        mavutil,
        open_mavlink,
    )

    link: Any
    if MAVLINK_CONNECTION.match(url):
        # pymavlink's own UDP/TCP links run on real time (no record/replay on this path).
        link = mavutil.mavlink_connection(
            url, source_system=GCS_SYSTEM_ID, source_component=GCS_COMPONENT_ID
        )
    else:
        serial_kwargs: dict[str, Any] = {}
        if url_scheme(url) not in CLOCK_AWARE_SCHEMES:
            serial_kwargs["baudrate"] = baudrate or DEFAULT_BAUD["mavlink"]
        link = open_mavlink(url, clock=clock, **serial_kwargs)
    try:
        output = factory(link, clock, autopilot=autopilot, **opts)
    except BaseException:
        link.close()
        raise
    if not isinstance(output, ThrottleOutput):
        link.close()
        raise TypeError(f"open_mavlink_output returned {type(output).__name__}")
    return output


def line_spec_for(
    url: str,
    *,
    line_preset: str | None = None,
    line_spec_file: str | None = None,
    detected_preset: str | None = None,
) -> LineStandSpec:
    """The spec to read a line stand with: a spec file, a preset, the sim URL's preset, or the
    preset its header matched."""
    if line_spec_file is not None and line_preset is not None:
        raise ConfigError("give either a line stand preset or a spec file, not both")
    if line_spec_file is not None:
        return load_line_spec(line_spec_file)
    if line_preset is not None:
        return preset(line_preset)
    peer = sim_peer(url)
    if peer is not None and peer[0] == "line-stand":
        return preset(_sim_line_preset(peer[1]))
    if detected_preset is not None:
        return preset(detected_preset)
    raise ConfigError(
        f"which line stand is on {url}? pass --line-preset ({', '.join(PRESETS)}) or "
        "--line-spec my-stand.json"
    )


def open_stand(
    url: str,
    clock: Clock,
    *,
    kind: str | None = None,
    calibration: str | None = None,
    line_preset: str | None = None,
    line_spec_file: str | None = None,
    baudrate: int | None = None,
    wait_s: float = 3.0,
) -> Stand:
    """Open the thrust stand at ``url`` (see module). A Tyto 1585 needs ``calibration`` (its
    load cells are raw; ``sim://tyto-1585`` uses the simulator's). A line stand is read with
    ``line_spec_file`` or ``line_preset`` (or the preset a ``sim://`` URL or its header names);
    it must send data within ``wait_s``."""
    if kind is None and (line_preset is not None or line_spec_file is not None):
        kind = "line-stand"
    elif kind is None and calibration is not None:
        kind = "tyto-1585"
    found = _resolve(url, clock, kind, baudrate)
    if found.kind in FC_KINDS:
        what = found.firmware or found.kind
        raise ConfigError(f"{url} is a flight controller ({what}), not a thrust stand")
    if found.kind == "tyto-1585":
        from thrustmap.rig.stand.tyto import TytoStand

        cal = _tyto_calibration(url, calibration)
        port = open_port(url, clock, baudrate=baudrate or DEFAULT_BAUD["tyto-1585"])
        try:
            return TytoStand(port, clock, cal)
        except BaseException:
            port.close()
            raise
    spec = line_spec_for(
        url,
        line_preset=line_preset,
        line_spec_file=line_spec_file,
        detected_preset=found.line_preset,
    )
    port = open_port(url, clock, baudrate=baudrate or spec.baudrate or DEFAULT_BAUD["line-stand"])
    stand = LineStand(port, clock, spec)
    try:
        stand.wait_for_data(wait_s)
    except BaseException:
        stand.close()
        raise
    return stand


def _tyto_calibration(url: str, path: str | None) -> TytoCalibration:
    if path is not None:
        return TytoCalibration.load(path)
    peer = sim_peer(url)
    if peer is not None:
        if "calibration" in peer[1]:
            return TytoCalibration.load(peer[1]["calibration"])
        # rig.sim.peers first: it registers the peers with the shared bench plant, and
        # importing stand_peers alone would put the plain stand-in plant back.
        importlib.import_module("thrustmap.rig.sim.peers")
        from thrustmap.rig.sim.stand_peers import SIM_TYTO_CALIBRATION

        return SIM_TYTO_CALIBRATION
    raise ConfigError(
        f"the Tyto 1585 on {url} reports raw load-cell counts: pass --calibration cal.json "
        "(tare and N per count of each cell)"
    )


# --------------------------------------------------------------------------- ports


class PortInfo(Protocol):
    """The part of ``serial.tools.list_ports_common.ListPortInfo`` used here."""

    device: str
    description: str
    hwid: str
    vid: int | None
    pid: int | None
    serial_number: str | None
    manufacturer: str | None
    product: str | None


@dataclass(frozen=True)
class PortDescription:
    device: str
    description: str
    vid: int | None
    pid: int | None
    manufacturer: str
    product: str
    serial_number: str
    guess: str
    kinds: tuple[str, ...] = ()  # device kinds worth trying, most likely first
    probe_safe: bool = True  # False for bootloaders (DFU): opening them is pointless

    @property
    def usb_id(self) -> str:
        if self.vid is None or self.pid is None:
            return ""
        return f"{self.vid:04X}:{self.pid:04X}"

    def to_dict(self) -> dict[str, object]:
        return {
            "device": self.device,
            "description": self.description,
            "usb_id": self.usb_id,
            "manufacturer": self.manufacturer,
            "product": self.product,
            "serial_number": self.serial_number,
            "guess": self.guess,
            "kinds": list(self.kinds),
        }


FC = ("msp", "mavlink")
#: (vid, pid or None for any) -> (guess, likely kinds). From the vendors' published USB IDs.
USB_IDS: dict[tuple[int, int | None], tuple[str, tuple[str, ...]]] = {
    (0x0483, 0x5740): (
        "STM32 virtual COM port: a flight controller (Betaflight/INAV; some ArduPilot/PX4 boards)",
        ("msp", "mavlink"),
    ),
    (0x0483, 0xDF11): ("STM32 in DFU bootloader mode (flashing, not a serial link)", ()),
    (0x2E3C, 0x5740): (
        "Artery AT32 virtual COM port: likely a Betaflight/INAV flight controller",
        ("msp",),
    ),
    (0x1209, 0x5740): ("ArduPilot ChibiOS board (e.g. Matek, CubeOrange)", ("mavlink",)),
    (0x1209, 0x5741): ("ArduPilot ChibiOS board, bootloader", ()),
    (0x26AC, None): ("PX4 FMU / 3DR Pixhawk (PX4 or ArduPilot)", ("mavlink",)),
    (0x2DAE, None): ("Hex/CubePilot Cube (ArduPilot or PX4)", ("mavlink",)),
    (0x3162, None): ("Holybro Pixhawk (PX4 or ArduPilot)", ("mavlink",)),
    (0x10C4, 0xEA60): (
        "CP210x USB-UART bridge: ESP32/DIY stand, FC UART or telemetry radio",
        ("line-stand", "mavlink", "msp"),
    ),
    (0x1A86, 0x7523): (
        "CH340 USB-UART bridge: Arduino-type board, a DIY line stand or a Tyto-like stand",
        ("line-stand", "tyto-1585"),
    ),
    (0x1A86, 0x55D4): ("CH9102 USB-UART bridge: ESP32 DIY stand", ("line-stand",)),
    (0x0403, 0x6001): (
        "FTDI FT232R USB-UART: Arduino-type stand, FC UART or telemetry radio",
        ("line-stand", "tyto-1585", "mavlink"),
    ),
    (0x0403, 0x6015): (
        "FTDI FT-X USB-UART: SiK telemetry radio (MAVLink) or a DIY stand",
        ("mavlink", "line-stand"),
    ),
    (0x0403, 0x6014): ("FTDI FT232H USB-UART", ("line-stand",)),
    (0x0403, 0x6010): ("FTDI FT2232 USB-UART", ("line-stand",)),
    (0x2341, None): ("Arduino board: a DIY line stand or a Tyto-like stand", ("line-stand",)),
    (0x2A03, None): ("Arduino board: a DIY line stand", ("line-stand",)),
    (0x2E8A, None): (
        "Raspberry Pi RP2040/RP2350: a DIY line stand (e.g. whoop stand)",
        ("line-stand",),
    ),
    (0x16C0, 0x0483): ("Teensy USB serial: a DIY line stand", ("line-stand",)),
    (0x303A, None): ("Espressif ESP32-S2/S3/C3 USB serial: a DIY line stand", ("line-stand",)),
    (0x239A, None): ("Adafruit board: a DIY line stand", ("line-stand",)),
}
#: words in the USB strings -> (guess, kinds); checked before the ID table
KEYWORDS: tuple[tuple[str, str, tuple[str, ...]], ...] = (
    ("betaflight", "Betaflight flight controller", ("msp",)),
    ("inav", "INAV flight controller", ("msp",)),
    ("ardupilot", "ArduPilot flight controller", ("mavlink",)),
    ("px4", "PX4 flight controller", ("mavlink",)),
    ("pixhawk", "Pixhawk flight controller (PX4 or ArduPilot)", ("mavlink",)),
    ("cube", "Cube flight controller (ArduPilot or PX4)", ("mavlink",)),
    ("rcbenchmark", "RCbenchmark / Tyto thrust stand", ("tyto-1585",)),
    ("tyto", "Tyto Robotics thrust stand", ("tyto-1585",)),
)


def describe_port(info: PortInfo) -> PortDescription:
    """A guess at what a serial port is, from its USB IDs and strings (the port is not opened)."""
    manufacturer = info.manufacturer or ""
    product = info.product or ""
    description = info.description or ""
    words = f"{manufacturer} {product} {description}".lower()
    guess = ""
    kinds: tuple[str, ...] = ()
    probe_safe = True
    for word, what, what_kinds in KEYWORDS:
        if re.search(rf"\b{re.escape(word)}", words):
            guess, kinds = what, what_kinds
            break
    if info.vid is not None:
        entry = USB_IDS.get((info.vid, info.pid)) if info.pid is not None else None
        if entry is None:
            entry = USB_IDS.get((info.vid, None))
        if entry is not None:
            if not entry[1] and ("bootloader" in entry[0] or "DFU" in entry[0]):
                probe_safe = False
            if not guess:
                guess, kinds = entry
            elif entry[0] not in guess:
                guess = f"{guess} ({entry[0].split(':')[0]})"
        elif not guess:
            guess = "unknown USB serial device"
            kinds = KINDS
    elif not guess:
        guess = "built-in or virtual serial port (no USB IDs)"
    return PortDescription(
        device=info.device,
        description=description,
        vid=info.vid,
        pid=info.pid,
        manufacturer=manufacturer,
        product=product,
        serial_number=info.serial_number or "",
        guess=guess,
        kinds=kinds,
        probe_safe=probe_safe,
    )


def list_ports() -> list[PortDescription]:
    """Every serial port pyserial sees, described (none is opened)."""
    from serial.tools import list_ports as lp

    return [describe_port(p) for p in sorted(lp.comports(), key=lambda p: p.device)]


# --------------------------------------------------------------------------- probe


@dataclass
class StandSummary:
    samples: int
    duration_s: float
    rate_hz: float | None
    means: dict[str, float]  # field -> mean over the window (fields the stand reports)
    bad_lines: int = 0


@dataclass
class ProbeReport:
    url: str
    detection: Detection
    identity: DeviceIdentity | None = None
    throttle_scale: str = ""
    telemetry: Telemetry | None = None
    motor_values: tuple[int, ...] | None = None
    stand: StandSummary | None = None
    warnings: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, object]:
        out: dict[str, object] = {
            "url": self.url,
            "kind": self.detection.kind,
            "firmware": self.detection.firmware,
            "evidence": self.detection.evidence,
            "identity": None if self.identity is None else self.identity.to_dict(),
            "throttle_scale": self.throttle_scale,
            "warnings": list(self.warnings),
        }
        if self.telemetry is not None:
            t = self.telemetry
            out["telemetry"] = {
                "voltage_v": t.voltage_v,
                "current_a": t.current_a,
                "rpm": None if t.rpm is None else list(t.rpm),
                "temperature_c": None if t.temperature_c is None else list(t.temperature_c),
            }
        if self.motor_values is not None:
            out["motor_values"] = list(self.motor_values)
        if self.stand is not None:
            out["stand"] = {
                "samples": self.stand.samples,
                "duration_s": self.stand.duration_s,
                "rate_hz": self.stand.rate_hz,
                "means": dict(self.stand.means),
                "bad_lines": self.stand.bad_lines,
            }
        return out


def summarize_samples(samples: Sequence[StandSample], duration_s: float) -> StandSummary:
    means: dict[str, float] = {}
    for name in ("thrust_n", "torque_nm", "voltage_v", "current_a", "rpm", "temperature_c"):
        values = [getattr(s, name) for s in samples if getattr(s, name) is not None]
        if values:
            means[name] = math.fsum(values) / len(values)
    rate = None
    if len(samples) >= 2 and samples[-1].time_s > samples[0].time_s:
        rate = (len(samples) - 1) / (samples[-1].time_s - samples[0].time_s)
    return StandSummary(len(samples), duration_s, rate, means)


def probe_device(
    url: str,
    clock: Clock,
    *,
    kind: str | None = None,
    baudrate: int | None = None,
    calibration: str | None = None,
    line_preset: str | None = None,
    line_spec_file: str | None = None,
    seconds: float = 1.0,
) -> ProbeReport:
    """Identify what is at ``url`` and take a short live reading. An FC is opened as a throttle
    output (its exit commands stop and verifies it, as always) but no motor is commanded."""
    found = _resolve(url, clock, kind, baudrate)
    report = ProbeReport(url, found)
    if found.kind in FC_KINDS:
        output = open_throttle_output(url, clock, kind=kind or found.kind, baudrate=baudrate)
        with output:
            try:
                report.identity = output.identify()
            except SafetyError as exc:
                report.warnings.append(str(exc))
            report.throttle_scale = output.throttle_scale.name
            try:
                report.telemetry = output.read_telemetry()
            except ThrustmapError as exc:
                report.warnings.append(f"no telemetry: {exc}")
            motor_values = getattr(output, "motor_values", None)
            if callable(motor_values):
                try:
                    report.motor_values = tuple(int(v) for v in motor_values())
                except ThrustmapError as exc:
                    report.warnings.append(f"no motor values: {exc}")
        return report
    stand = open_stand(
        url,
        clock,
        kind=found.kind,
        calibration=calibration,
        line_preset=line_preset,
        line_spec_file=line_spec_file,
        baudrate=baudrate,
    )
    with stand:
        report.identity = stand.identify()
        start = clock.now_s()
        samples: list[StandSample] = []
        while True:
            samples += stand.read_samples()
            if clock.now_s() - start >= seconds:
                break
            clock.sleep_s(0.02)
        report.stand = summarize_samples(samples, clock.now_s() - start)
        if isinstance(stand, LineStand):
            report.stand.bad_lines = stand.error_count
            report.identity = stand.identify()
    return report
