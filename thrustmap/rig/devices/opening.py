"""Opening a device by URL through the driver registry: a flight controller or a stand's own
ESC as a throttle output (``open_throttle_output``), a thrust stand (``open_stand``), and the ESC
output of an open stand (``stand_esc_output``).

Below ``probe`` (which opens what it reports on) and the bench session (``rig.session``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from thrustmap.core.clock import Clock
from thrustmap.core.errors import ConfigError
from thrustmap.rig.devices.declaration import OpenRequest
from thrustmap.rig.devices.detect import resolve
from thrustmap.rig.devices.registry import driver, drivers
from thrustmap.rig.interfaces import DeviceIdentity, Stand, Telemetry, ThrottleOutput


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

    def stop_and_verify(self, attempts: int = 3, *, alarm: bool = True) -> bool:
        return self.inner.stop_and_verify(attempts, alarm=alarm)

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
    for drv in drivers():
        if drv.esc_output is not None:
            output = drv.esc_output(stand, motor)
            if output is not None:
                return output
    raise ConfigError(f"a {type(stand).__name__} cannot drive an ESC")


@dataclass(frozen=True)
class StandEscSpec:
    """How to open a stand whose own ESC is the throttle output (``tyto-1585``,
    ``line-stand``): the motor it drives, a Tyto 1585's load-cell ``calibration``, a line
    stand's ``line_preset`` or ``line_spec_file`` (as ``open_stand`` takes them)."""

    motor: int = 0
    calibration: str | None = None
    line_preset: str | None = None
    line_spec_file: str | None = None


def open_throttle_output(
    url: str,
    clock: Clock,
    *,
    kind: str | None = None,
    baudrate: int | None = None,
    stand_esc: StandEscSpec | None = None,
    watchdog_log: str | None = None,
    signing_key: Any = None,
    **opts: Any,
) -> ThrottleOutput:
    """Open whatever commands motor throttle at ``url``.

    ``watchdog_log``: where an MSP output's motor-stop watchdog process logs (default: the
    user's state folder); other outputs time out by themselves and start no watchdog.

    ``signing_key``: a MAVLink 2 signing key (``protocols.mavlink.signing.SigningKey``) for a
    MAVLink vehicle; refused for any other kind, unless it came from the environment variable
    (then ignored).

    ``kind`` (see module) is detected when None. ``opts`` go to the driver's constructor
    (``MspThrottleOutput(timeout_s=, retries=)``) or to ``open_mavlink_output``. For a stand's
    own ESC output (``tyto-1585``, ``line-stand``) ``stand_esc`` says how to open the stand and
    which motor it drives (default: motor 0, the stand as detected), and the returned output
    owns the stand (``.stand``; closing the output closes it).
    """
    found = resolve(url, clock, kind, baudrate)
    drv = driver(found.kind)
    if watchdog_log is not None and found.kind == "msp":
        opts["watchdog_log"] = watchdog_log
    if signing_key is not None and found.kind != "mavlink":
        if not getattr(signing_key, "from_environment", False):
            raise ConfigError(
                f"--signing-key is for MAVLink vehicles (PX4, ArduPilot); {url} is {found.kind}"
            )
        signing_key = None  # the environment's key is for MAVLink devices only
    if signing_key is not None:
        opts["signing_key"] = signing_key
    if drv.open_output is not None:
        return drv.open_output(
            OpenRequest(url, clock, baudrate, firmware=found.firmware, opts=dict(opts))
        )
    esc = stand_esc or StandEscSpec()
    stand = open_stand(
        url,
        clock,
        kind=found.kind,
        calibration=esc.calibration,
        line_preset=esc.line_preset or found.line_preset,
        line_spec_file=esc.line_spec_file,
        baudrate=baudrate,
    )
    try:
        return StandEscOutput(stand_esc_output(stand, esc.motor), stand)
    except BaseException:
        stand.close()
        raise


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
    found = resolve(url, clock, kind, baudrate)
    drv = driver(found.kind)
    if drv.open_stand is None:
        what = found.firmware or found.kind
        raise ConfigError(f"{url} is a flight controller ({what}), not a thrust stand")
    return drv.open_stand(
        OpenRequest(
            url,
            clock,
            baudrate,
            firmware=found.firmware,
            calibration=calibration,
            line_preset=line_preset,
            line_spec_file=line_spec_file,
            detected_preset=found.line_preset,
            wait_s=wait_s,
        )
    )
