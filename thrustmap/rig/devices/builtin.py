"""The built-in drivers: MSP and MAVLink flight controllers, the Tyto 1585 and line stands.

Each is ONE declaration (``declaration.Driver``): its names, how to recognise it, how to open it.
Driver modules are imported only when a device of their kind is opened.
"""

from __future__ import annotations

import importlib
import re
from collections.abc import Mapping, Sequence
from typing import Any

from thrustmap.core.errors import ConfigError, ThrustmapError
from thrustmap.protocols.stands.line import LineStandSpec
from thrustmap.protocols.stands.line_presets import aliases, preset, presets
from thrustmap.protocols.stands.tyto import TYTO_READY_LINE, TytoCalibration
from thrustmap.rig.devices.declaration import Detection, Driver, OpenRequest
from thrustmap.rig.devices.urls import (
    CLOCK_AWARE_SCHEMES,
    MAVLINK_CONNECTION,
    innermost_url,
    load_sim_peers,
    open_port,
    sim_peer,
    url_scheme,
)
from thrustmap.rig.interfaces import Stand, ThrottleOutput

# --------------------------------------------------------------------------- MSP


def _msp_sim(name: str, options: Mapping[str, str]) -> Detection | None:
    if name not in ("betaflight", "inav"):
        return None
    firmware = "inav" if name == "inav" or options.get("firmware", "").startswith("inav") else name
    return Detection("msp", firmware, evidence=f"simulated peer sim://{name}")


def _open_msp(req: OpenRequest) -> ThrottleOutput:
    from thrustmap.rig.fc.msp import MspThrottleOutput, msp_port_url

    baud = req.baudrate or MSP.default_baud
    port = open_port(msp_port_url(req.url), req.clock, baudrate=baud)
    try:  # url and baud: the motor-stop watchdog reopens the same port
        return MspThrottleOutput(port, req.clock, url=req.url, baudrate=baud, **req.opts)
    except BaseException:
        port.close()
        raise


MSP = Driver(
    kind="msp",
    role="fc",
    description="Betaflight/INAV flight controller over MSP",
    default_baud=115200,
    aliases={"msp": None, "betaflight": "betaflight", "inav": "inav"},
    sim_detect=_msp_sim,
    host_prefixes=(b"$M<", b"$X<"),
    open_output=_open_msp,
    verified="against real Betaflight 4.6.0 SITL (in CI, on every change)",
)

# --------------------------------------------------------------------------- MAVLink


def _mavlink_sim(name: str, options: Mapping[str, str]) -> Detection | None:
    if name not in ("px4", "ardupilot"):
        return None
    return Detection("mavlink", name, evidence=f"simulated peer sim://{name}")


def _mavlink_classify(data: bytes, lines: list[str]) -> Detection | None:
    from thrustmap.protocols.mavlink.codec import MavlinkCodec, decode_heartbeat

    for msg in MavlinkCodec().feed(data):
        if msg.get_type() == "HEARTBEAT":
            hb = decode_heartbeat(msg)
            if hb.is_vehicle:
                firmware = hb.firmware if hb.firmware != "other" else None
                return Detection(
                    "mavlink", firmware, evidence=f"MAVLink HEARTBEAT (autopilot {hb.autopilot})"
                )
    return None


def _open_mavlink(req: OpenRequest) -> ThrottleOutput:
    url, clock = req.url, req.clock
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
        is_own_transport,
        mavutil_connection,
        open_mavlink,
    )

    link: Any
    if url_scheme(innermost_url(url)) == "sim":
        load_sim_peers()
    if MAVLINK_CONNECTION.match(url) and not is_own_transport(url):
        # tcpin:, udpbcast: pymavlink's own links, on real time (no record/replay on this path)
        try:
            link = mavutil_connection(url, retries=0)
        except (OSError, ValueError) as exc:  # refused, unreachable, bad host:port
            raise ConfigError(f"cannot open {url}: {exc}") from None
    else:
        serial_kwargs: dict[str, Any] = {}
        if url_scheme(url) not in CLOCK_AWARE_SCHEMES:
            serial_kwargs["baudrate"] = req.baudrate or MAVLINK.default_baud
        try:
            link = open_mavlink(url, clock=clock, **serial_kwargs)
        except ThrustmapError:
            raise
        except (OSError, ValueError) as exc:  # serial.SerialException is an OSError
            raise ConfigError(f"cannot open {url}: {exc}") from None
    try:
        output = factory(link, clock, autopilot=req.firmware, **req.opts)
    except BaseException:
        link.close()
        raise
    if not isinstance(output, ThrottleOutput):
        link.close()
        raise TypeError(f"open_mavlink_output returned {type(output).__name__}")
    return output


MAVLINK = Driver(
    kind="mavlink",
    role="fc",
    description="PX4/ArduPilot flight controller over MAVLink",
    default_baud=115200,
    aliases={"mavlink": None, "px4": "px4", "ardupilot": "ardupilot"},
    sim_detect=_mavlink_sim,
    classify=_mavlink_classify,
    host_prefixes=(b"\xfd", b"\xfe"),
    open_output=_open_mavlink,
    verified="against ArduCopter 4.7-dev and PX4 v1.17 SITL (docs/mavlink.md)",
)

# --------------------------------------------------------------------------- Tyto 1585


def _tyto_sim(name: str, options: Mapping[str, str]) -> Detection | None:
    if name != "tyto-1585":
        return None
    return Detection("tyto-1585", evidence=f"simulated peer sim://{name}")


def _tyto_classify(data: bytes, lines: list[str]) -> Detection | None:
    if TYTO_READY_LINE in lines:
        return Detection("tyto-1585", evidence=f"'{TYTO_READY_LINE}' banner")
    return None


def tyto_calibration(url: str, path: str | None) -> TytoCalibration:
    """The calibration to read the Tyto at ``url`` with: the file given, the ``sim://`` URL's
    ``calibration=`` file, or the one its simulator registered."""
    from thrustmap.rig.stand.tyto import load_calibration, simulated_calibration

    if path is not None:
        return load_calibration(path)
    peer = sim_peer(url)
    if peer is not None:
        if "calibration" in peer[1]:
            return load_calibration(peer[1]["calibration"])
        load_sim_peers()  # the simulator registers the calibration its peers were built with
        cal = simulated_calibration(peer[0])
        if cal is not None:
            return cal
    raise ConfigError(
        f"the Tyto 1585 on {url} reports raw load-cell counts: pass --calibration cal.json "
        "(tare and N per count of each cell)"
    )


def _open_tyto(req: OpenRequest) -> Stand:
    from thrustmap.rig.stand.tyto import TytoStand

    cal = tyto_calibration(req.url, req.calibration)
    port = open_port(req.url, req.clock, baudrate=req.baudrate or TYTO.default_baud)
    try:
        return TytoStand(port, req.clock, cal)
    except BaseException:
        port.close()
        raise


def _tyto_esc(stand: Stand, motor: int) -> ThrottleOutput | None:
    from thrustmap.rig.stand.tyto import TytoEscOutput, TytoStand

    return TytoEscOutput(stand, motor) if isinstance(stand, TytoStand) else None


TYTO = Driver(
    kind="tyto-1585",
    role="stand",
    description="Tyto Robotics Series 1585 thrust stand",
    default_baud=250000,
    aliases={"tyto": None, "tyto-1585": None},
    sim_detect=_tyto_sim,
    classify=_tyto_classify,
    host_prefixes=(b"$R<",),
    open_stand=_open_tyto,
    esc_output=_tyto_esc,
    verified="written from documentation only: not checked against a Series 1585 or an "
    "official client",
)

# --------------------------------------------------------------------------- line stands


def sim_line_preset(options: Mapping[str, str]) -> str:
    """The line preset a ``sim://line-stand`` URL asks for (``line_preset=`` or ``preset=``)."""
    for key in ("line_preset", "preset"):
        name = options.get(key, "").lower()
        if name in presets() or name in aliases():
            return preset(name).name
    return "thrustmap-line"


def _line_sim(name: str, options: Mapping[str, str]) -> Detection | None:
    if name != "line-stand":
        return None
    return Detection("line-stand", None, sim_line_preset(options), f"simulated peer sim://{name}")


def _header_preset(names: Sequence[str]) -> str | None:
    lower = {n.lower() for n in names}
    exact = [
        s.name for s in presets().values() if s.header_names and tuple(names) == s.header_names
    ]
    if exact:
        return exact[0]  # a preset printing this very header before one reading some of it
    for spec in presets().values():
        named = [c.name.lower() for c in spec.columns.values() if c.name is not None]
        if named and all(n in lower for n in named) and spec.header_names:
            return spec.name
    return None


_NUMBER = re.compile(r"^[-+]?(\d+(\.\d*)?|\.\d+)([eE][-+]?\d+)?$")


def _line_classify(data: bytes, lines: list[str]) -> Detection | None:
    for line in lines:
        if line.startswith("#COLS"):
            names = [n for n in re.split(r"[,\s;]+", line[len("#COLS") :].strip()) if n]
            return Detection(
                "line-stand", line_preset=_header_preset(names), evidence=f"header '{line[:60]}'"
            )
    from thrustmap.protocols.stands.line_presets import identify

    texts = [ln for ln in lines[1:] if ln]  # the first line may have been cut short
    matched = identify(texts)
    if len(matched) == 1:
        return Detection(
            "line-stand",
            line_preset=matched[0].name,
            evidence=f"{len(texts)} lines as {matched[0].name} prints them: {texts[0][:40]!r}",
        )
    numeric = 0
    widths: set[int] = set()
    for line in texts:
        cells = [c for c in re.split(r"[,;\s]+", line) if c]
        if len(cells) >= 2 and all(_NUMBER.match(c) for c in cells):
            numeric += 1
            widths.add(len(cells))
    if numeric >= 3 and len(widths) == 1:
        width = widths.pop()
        which = (
            f"matches presets {', '.join(s.name for s in matched)}"
            if matched
            else "matches no preset"
        )
        return Detection(
            "line-stand",
            evidence=f"{numeric} numeric lines of {width} fields ({which}); first lines: "
            + " | ".join(repr(t[:60]) for t in texts[:3]),
        )
    return None


def line_spec_for(
    url: str,
    *,
    line_preset: str | None = None,
    line_spec_file: str | None = None,
    detected_preset: str | None = None,
) -> LineStandSpec:
    """The spec to read a line stand with: a spec file, a preset, the sim URL's preset, or the
    preset its header matched."""
    from thrustmap.rig.stand.line_spec import load_line_spec

    if line_spec_file is not None and line_preset is not None:
        raise ConfigError("give either a line stand preset or a spec file, not both")
    if line_spec_file is not None:
        return load_line_spec(line_spec_file)
    if line_preset is not None:
        return preset(line_preset)
    peer = sim_peer(url)
    if peer is not None and peer[0] == "line-stand":
        return preset(sim_line_preset(peer[1]))
    if detected_preset is not None:
        return preset(detected_preset)
    raise ConfigError(
        f"which line stand is on {url}? pass --line-preset ({', '.join(presets())}) or "
        "--line-spec my-stand.json"
    )


def _open_line(req: OpenRequest) -> Stand:
    from thrustmap.rig.stand.line import LineStand

    spec = line_spec_for(
        req.url,
        line_preset=req.line_preset,
        line_spec_file=req.line_spec_file,
        detected_preset=req.detected_preset,
    )
    if req.calibration is not None:
        from thrustmap.rig.stand.line_calibration import load_line_calibration

        spec = load_line_calibration(req.calibration).apply(spec, req.calibration)
    baud = req.baudrate or spec.baudrate or LINE.default_baud
    stand = LineStand(open_port(req.url, req.clock, baudrate=baud), req.clock, spec)
    if spec.sequence_start is not None:
        return stand  # silent until its sequence is started: nothing to wait for
    try:
        stand.wait_for_data(req.wait_s)
    except BaseException:
        stand.close()
        raise
    return stand


def _line_esc(stand: Stand, motor: int) -> ThrottleOutput | None:
    from thrustmap.rig.stand.line import LineStand, LineStandEscOutput

    if not isinstance(stand, LineStand):
        return None
    if not stand.spec.drives_esc:
        raise ConfigError(
            f"line stand '{stand.spec.name}' cannot drive an ESC (its firmware only measures): "
            "pass --throttle with the flight controller that drives the motor; it also stops it"
        )
    if not stand.spec.takes_throttle:
        raise ConfigError(
            f"line stand '{stand.spec.name}' takes no throttle from the host (it runs its own "
            "programs): use thrustmap stand run, or pass --throttle with a flight controller"
        )
    return LineStandEscOutput(stand, motor)


LINE = Driver(
    kind="line-stand",
    role="stand",
    description="line stand: a DIY/commercial stand streaming text lines (presets or a spec)",
    default_baud=115200,
    aliases={"line": None, "line-stand": None},
    sim_detect=_line_sim,
    classify=_line_classify,
    open_stand=_open_line,
    esc_output=_line_esc,
    verified="thrustmap's own line format and presets written from their projects' "
    "documentation: not checked against a device",
)

# --------------------------------------------------------------------------- Flight Stand


def _open_flightstand(req: OpenRequest) -> Stand:
    from thrustmap.rig.stand.flightstand import FlightStandStand

    return FlightStandStand(req.url, req.clock)


def _flightstand_esc(stand: Stand, motor: int) -> ThrottleOutput | None:
    from thrustmap.rig.stand.flightstand import FlightStandEscOutput, FlightStandStand

    return FlightStandEscOutput(stand, motor) if isinstance(stand, FlightStandStand) else None


FLIGHTSTAND = Driver(
    kind="flightstand",
    role="stand",
    description="Tyto Robotics Flight Stand (15/50/150/500) through its official Python API",
    default_baud=0,
    aliases={"flightstand": None, "flight-stand": None},
    open_stand=_open_flightstand,
    esc_output=_flightstand_esc,
    url_schemes=("flightstand",),
    verified="against Tyto's official client (package flightstand 3.0.2: its generated gRPC "
    "classes and example scripts) talking to thrustmap's simulated core; not yet against a "
    "real Flight Stand core",
)

#: detection order: a MAVLink HEARTBEAT first, then the Tyto banner, then line-stand text
BUILTIN: tuple[Driver, ...] = (MSP, MAVLINK, TYTO, LINE, FLIGHTSTAND)
