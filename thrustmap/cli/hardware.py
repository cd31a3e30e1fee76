"""``thrustmap ports``, ``thrustmap probe URL`` and ``thrustmap spin URL``: talk to the hardware.

Thin layers over ``thrustmap.rig.devices`` and ``thrustmap.rig.spin``. URLs are device paths
(``/dev/ttyACM0``, ``COM3``), ``sim://<peer>`` simulated devices, ``record://<url>?file=x.jsonl``
and ``replay://x.jsonl``, or ``socket://host:port``.

Clock: with ``--clock auto`` (the default) a URL with nothing real behind it (``sim://``,
``replay://``) runs on a simulated clock — instantly, and nothing waits for real — and any real
device on the monotonic clock. ``--clock real`` watches a simulation in real time.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import sys
from typing import TYPE_CHECKING, Any

import click

from thrustmap.cli.bench import limit_options_except
from thrustmap.cli.mavlink_options import signing_key_option
from thrustmap.cli.textwidth import echo
from thrustmap.core.clock import Clock, MonotonicClock
from thrustmap.core.errors import ConfigError, ThrustmapError
from thrustmap.rig.interlocks import SPIN_MAX_SECONDS as MAX_SECONDS
from thrustmap.rig.interlocks import SPIN_MAX_THROTTLE_PCT as DEFAULT_MAX_THROTTLE_PCT
from thrustmap.rig.interlocks import Limits

if TYPE_CHECKING:  # drivers (pyserial, numpy, pymavlink) load when a command runs
    from thrustmap.protocols.mavlink.signing import SigningKey
    from thrustmap.rig.devices.ports import PortDescription
    from thrustmap.rig.spin import SpinReport

log = logging.getLogger(__name__)

#: the interlocks spin sets its own way (a 20 % cap by default; one level, no ramp to check)
SPIN_OWN_LIMITS = ("max_throttle_pct", "max_slew_pct_s")
CLOCK_CHOICE = click.Choice(["auto", "real", "sim"], case_sensitive=False)  # rig.session


def make_clock(choice: str, urls: list[str]) -> Clock:
    """The clock for a command on ``urls`` (the rule: ``thrustmap.rig.session.choose_clock``)."""
    from thrustmap.rig.session import choose_clock

    return choose_clock(urls, choice)


def _device_options(fn: click.decorators.FC) -> click.decorators.FC:
    options = [
        click.option(
            "--kind",
            default=None,
            help="What is connected: msp (betaflight, inav), mavlink (px4, ardupilot), "
            "tyto-1585 or line-stand (default: detected by a safe probe).",
        ),
        click.option("--baud", type=int, default=None, help="Serial baud rate (default by kind)."),
        click.option(
            "--calibration",
            type=click.Path(dir_okay=False),
            default=None,
            help="Load-cell calibration (JSON): a Tyto 1585's, or a line stand's from "
            "thrustmap stand calibrate.",
        ),
        click.option(
            "--line-preset",
            default=None,
            help="Line stand preset (e.g. thrustmap-line, tiny-thrust-stand, "
            "victorhook-thruststand).",
        ),
        click.option(
            "--line-spec",
            type=click.Path(dir_okay=False),
            default=None,
            help="Line stand description (JSON) for your own stand.",
        ),
        click.option(
            "--clock",
            "clock_choice",
            type=CLOCK_CHOICE,
            default="auto",
            show_default=True,
            help="auto: simulated time for sim:// and replay:// URLs, real time otherwise.",
        ),
    ]
    for option in reversed(options):
        fn = option(fn)
    return fn


# --------------------------------------------------------------------------- ports


@click.command("ports")
@click.option("--probe", is_flag=True, help="Open each port and probe it safely (see probe).")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
@click.option("--listen", type=float, default=2.0, show_default=True, help="Seconds per probe.")
def ports_cmd(probe: bool, as_json: bool, listen: float) -> None:
    """List serial ports with a guess at what each is (from USB IDs; nothing is opened
    unless --probe)."""

    import thrustmap.rig.devices.ports as devices_ports

    ports = devices_ports.list_ports()
    rows: list[dict[str, object]] = []
    for port in ports:
        row = port.to_dict()
        if probe:
            row["probe"] = _probe_port(port, listen)
        rows.append(row)
    if as_json:
        click.echo(json.dumps(rows, indent=2))
        return
    if not rows:
        echo("no serial ports found")
        return
    width = max(len(p.device) for p in ports)
    for port, row in zip(ports, rows, strict=True):
        usb = port.usb_id or "-        "
        label = port.product or port.description
        echo(f"{port.device:<{width}}  {usb}  {port.guess}")
        if label and label not in port.guess:
            echo(f"{'':<{width}}             {label}")
        if "probe" in row:
            echo(f"{'':<{width}}             probe: {row['probe']}")


def _probe_port(port: PortDescription, listen_s: float) -> str:

    import thrustmap.rig.devices.detect as detect

    if not port.probe_safe:
        return "skipped (bootloader)"
    try:
        found = detect.detect_kind(port.device, MonotonicClock(), listen_s=listen_s)
    except ConfigError as exc:
        return f"unknown ({exc.message})"
    what = found.kind + (f" ({found.firmware})" if found.firmware else "")
    if found.line_preset:
        what += f", preset {found.line_preset}"
    return f"{what} — {found.evidence}"


# --------------------------------------------------------------------------- probe


@click.command("probe")
@click.argument("url")
@_device_options
@click.option("--seconds", type=float, default=1.0, show_default=True, help="Stand reading window.")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
@signing_key_option
def probe_cmd(
    url: str,
    kind: str | None,
    baud: int | None,
    calibration: str | None,
    line_preset: str | None,
    line_spec: str | None,
    clock_choice: str,
    seconds: float,
    as_json: bool,
    signing_key: SigningKey | None,
) -> None:
    """Identify the FC or stand at URL and take a short live reading (no motor is spun)."""
    if not 0 < seconds <= 60:
        raise ConfigError(f"--seconds must be in (0, 60], got {seconds:g}")
    clock = make_clock(clock_choice, [url])

    import thrustmap.rig.devices.probe as devices_probe
    from thrustmap.rig.devices.probe import StandOptions

    if kind is None and (line_preset is not None or line_spec is not None):
        kind = "line-stand"  # a silent stand (one that waits for its start) is named by them
    report = devices_probe.probe_device(
        url,
        clock,
        kind=kind,
        baudrate=baud,
        stand=StandOptions(calibration, line_preset, line_spec),
        seconds=seconds,
        signing_key=signing_key,
    )
    if as_json:
        click.echo(json.dumps(report.to_dict(), indent=2))
        return
    det = report.detection
    echo(f"{url}: {det.kind}" + (f" ({det.firmware})" if det.firmware else ""))
    echo(f"  found by: {det.evidence}")
    ident = report.identity
    if ident is not None:
        for label, value in (
            ("device", ident.kind),
            ("firmware", ident.firmware_version),
            ("board", ident.board),
            ("motor protocol", ident.motor_protocol),
            ("motors", ident.motor_count or ""),
            ("battery cells", ident.battery_cells or ""),
        ):
            if value:
                echo(f"  {label}: {value}")
        for key, value in sorted(ident.details.items()):
            echo(f"  {key}: {value}")
    if report.throttle_scale:
        echo(f"  throttle scale: {report.throttle_scale}")
    tel = report.telemetry
    if tel is not None:
        current = "current not measured" if tel.current_a is None else _fmt(tel.current_a, "A", 2)
        echo(f"  battery: {_fmt(tel.voltage_v, 'V', 2)}  {current}")
        if tel.rpm is not None:
            echo("  rpm: " + " ".join(f"{r:.0f}" for r in tel.rpm))
    if report.motor_values is not None:
        echo("  motor values: " + " ".join(str(v) for v in report.motor_values))
    stand = report.stand
    if stand is not None:
        rate = f" at {stand.rate_hz:.0f} Hz" if stand.rate_hz else ""
        echo(f"  {stand.samples} samples in {stand.duration_s:.2f} s{rate}")
        units = {
            "thrust_n": "N",
            "torque_nm": "N·m",
            "voltage_v": "V",
            "current_a": "A",
            "rpm": "rpm",
            "temperature_c": "°C",
        }
        for key, mean in stand.means.items():
            echo(f"  mean {key.rsplit('_', 1)[0]}: {mean:.4g} {units.get(key, '')}")
        if stand.bad_lines:
            echo(f"  bad lines: {stand.bad_lines}")
    for warning in report.warnings:
        echo(f"  warning: {warning}")


def _fmt(value: float | None, unit: str, digits: int) -> str:
    return "-" if value is None else f"{value:.{digits}f} {unit}"


# --------------------------------------------------------------------------- spin


@click.command("spin")
@click.argument("url")
@click.option(
    "--motor",
    required=True,
    help="The FC's motor number, 1-based (ArduPilot MotorN, PX4 MOTOR N, Betaflight motor N);"
    " on ArduPilot also the test-order letter (A, B, ...).",
)
@click.option(
    "--throttle",
    type=float,
    required=True,
    help="Throttle in percent of the output's scale (e.g. 10).",
)
@click.option(
    "--seconds",
    type=float,
    default=2.0,
    show_default=True,
    help=f"How long to hold it (at most {MAX_SECONDS:g} s).",
)
@click.option(
    "--max-throttle",
    type=float,
    default=DEFAULT_MAX_THROTTLE_PCT,
    show_default=True,
    help="Refuse throttle above this percent; raise it explicitly for more.",
)
@click.option("--ramp", type=float, default=0.5, show_default=True, help="Ramp-up time, s.")
@click.option("--yes", is_flag=True, help="Do not ask for confirmation.")
@click.option("--stand", "stand_url", default=None, help="Also show thrust from this stand.")
@_device_options
@signing_key_option
@limit_options_except(*SPIN_OWN_LIMITS)
def spin_cmd(
    url: str,
    motor: str,
    throttle: float,
    seconds: float,
    max_throttle: float,
    ramp: float,
    yes: bool,
    stand_url: str | None,
    kind: str | None,
    baud: int | None,
    calibration: str | None,
    line_preset: str | None,
    line_spec: str | None,
    clock_choice: str,
    signing_key: SigningKey | None,
    **limit_values: Any,
) -> None:
    """Spin ONE motor briefly at a low throttle: a capped, confirmed motor test.

    The motor is stopped and the stop verified on every way out (the end, an error, Ctrl-C,
    SIGTERM).

    \b
    Exit codes:
      0    done (stop verified)
      1    aborted by a device failure (stop verified)
      2    refused or bad input (nothing spun)
      3    stop NOT verified (disconnect the battery)
      130  interrupted by Ctrl-C/SIGTERM (stop verified)"""
    from thrustmap.cli.live import LiveView
    from thrustmap.cli.spin_confirm import confirm_spin
    from thrustmap.rig.fc.motor_numbers import parse_motor
    from thrustmap.rig.session import BenchSession, Rig, exit_code, pairing_warnings
    from thrustmap.rig.spin import SpinRequest, check_spin

    motor_number, _ = parse_motor(motor)  # refuse a bad --motor before anything is opened
    request = SpinRequest((motor_number or 1) - 1, throttle, seconds, ramp_s=ramp)
    check_spin(request, max_throttle)  # refuse before anything is opened
    limits = Limits.from_options(limit_values)  # every threshold, also before anything opens
    from thrustmap.rig.sim.pairing import pair_sim_urls

    rig = Rig(
        stand=None if stand_url is None else pair_sim_urls(stand_url, url),
        throttle=url,
        kind=kind,
        baudrate=baud,
        calibration=calibration,
        line_preset=line_preset,
        line_spec=line_spec,
        motor=request.motor,
        signing_key=signing_key,
    )
    clock = make_clock(clock_choice, rig.urls())
    for warning in pairing_warnings(rig):
        echo(f"warning: {warning}", err=True)
    confirm_spin(
        f"Motor {motor} on {url} will spin at {throttle:g} % for {seconds:g} s.\n"
        "Propellers on? The stand must be secured and the area clear. Spin now?",
        yes=yes,
    )
    session = BenchSession(rig, clock)
    try:
        with session:
            index, label = session.resolve_motor(motor)
            request = dataclasses.replace(request, motor=index)
            echo(f"spinning {label}")
            unit = session.output.throttle_scale.unit
            number = index + 1
            with LiveView(f"spin {label}", total_s=seconds, phase="spinning") as view:
                result = session.spin(
                    request,
                    max_throttle_pct=max_throttle,
                    limits=limits,
                    on_report=(lambda r: view.spin_report(r, number, unit, seconds))
                    if view.live
                    else (lambda r: echo(_report_line(r, number, unit))),
                )
    except KeyboardInterrupt:  # while opening the devices (a spin reports its own)
        verified = session.stop_verified is not False
        echo("interrupted; " + ("stop verified" if verified else "STOP NOT VERIFIED"))
        sys.exit(exit_code("interrupted", verified))
    verified = result.stop_verified and session.stop_verified is not False
    number = request.motor + 1
    if verified:
        echo(f"motor {number} stopped (verified) after {result.duration_s:.1f} s")
    elif session.stop_unverifiable:
        echo(
            f"motor {number}: stop sent and acknowledged, NOT verified: "
            f"{session.stop_unverifiable}",
            err=True,
        )
    else:
        echo(f"STOP NOT VERIFIED on motor {number} - disconnect the battery now", err=True)
    if result.status == "interrupted":
        echo(f"spin {result.reason}", err=True)
    elif result.status == "failed" and (not verified or result.max_commanded_pct > 0):
        echo(f"error: {result.reason}", err=True)
        if verified and not isinstance(result.error, ThrustmapError):
            result.raise_error()  # a bug in a driver: the CLI reports it as an internal error
    else:
        result.raise_error()  # refused before anything was commanded: exit 2
    code = exit_code("aborted" if result.status == "failed" else result.status, verified)
    if code:
        sys.exit(code)


def native_text(value: float, unit: str) -> str:
    """A throttle in its native scale: "1100 µs"; a dimensionless one (unit "1", PX4's
    normalised 0..1) as the bare fraction, "0.100"."""
    if unit in ("1", ""):
        return f"{value:.3f}"
    return f"{value:.4g} {unit}"


def _report_line(report: SpinReport, motor: int, unit: str) -> str:
    parts = [
        f"t={report.elapsed_s:4.1f}s",
        f"motor {motor}",
        f"{report.throttle_pct:5.1f} % ({native_text(report.throttle_native, unit)})",
    ]
    tel = report.telemetry
    if tel is not None:
        if tel.voltage_v is not None:
            parts.append(f"{tel.voltage_v:.2f} V")
        if tel.current_a is not None:
            parts.append(f"{tel.current_a:.2f} A")
        if tel.rpm is not None and len(tel.rpm) > 0:
            rpm = tel.rpm[motor - 1] if motor - 1 < len(tel.rpm) else tel.rpm[0]
            parts.append(f"{rpm:.0f} rpm")
    if report.stand is not None:
        parts.append(f"thrust {report.stand.thrust_n:.3f} N")
    return "  ".join(parts)
