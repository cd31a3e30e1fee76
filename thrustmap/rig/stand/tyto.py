"""Tyto Robotics Series 1585 stand over its serial protocol (``protocols.tyto``).

``TytoStand`` streams samples: each ``read_samples`` sends one poll (which carries the ESC
pulse the stand outputs) and decodes the reply through the unit's calibration into SI, pulling
thrust positive. ``TytoEscOutput`` uses the stand's own ESC output as the throttle output, as
the seed paper's RCbenchmark scripts did; when a flight controller drives the ESC instead, the
stand keeps sending the stop pulse (1000 µs), which the ESC does not see.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from thrustmap.core.clock import Clock
from thrustmap.core.errors import SafetyError, ThrustmapError
from thrustmap.core.files import atomic_write_text
from thrustmap.core.jsonfile import Fields, load_json
from thrustmap.core.units import SCALES
from thrustmap.protocols.stands.tyto import (
    LoadCell,
    TytoCalibration,
    TytoDecoder,
    TytoPoll,
    TytoReading,
    TytoReady,
)
from thrustmap.protocols.transport import SerialLike
from thrustmap.rig.interfaces import DeviceIdentity, Stand, StandSample, Telemetry, ThrottleOutput

log = logging.getLogger(__name__)

STOP_US = 1000


class TytoTimeout(ThrustmapError):
    """The stand did not answer (no ``Ready`` banner, or no reply to a poll)."""


class TytoStand(Stand):
    def __init__(
        self,
        port: SerialLike,
        clock: Clock,
        calibration: TytoCalibration,
        *,
        ready_timeout_s: float = 4.0,
        reply_timeout_s: float = 0.1,
    ) -> None:
        self.port = port
        self.clock = clock
        self.calibration = calibration
        self.reply_timeout_s = reply_timeout_s
        self.esc_us = STOP_US
        self.drives_esc = False
        self._decoder = TytoDecoder(">")
        self.port.timeout = 0.0
        self._ready = False
        self._wait_ready(ready_timeout_s)

    def _wait_ready(self, timeout_s: float) -> None:
        deadline = self.clock.now_s() + timeout_s
        while self.clock.now_s() < deadline:
            data = self.port.read(max(1, self.port.in_waiting))
            if any(isinstance(e, TytoReady) for e in self._decoder.feed_events(data)):
                self._ready = True
                return
            if not data:
                self.clock.sleep_s(0.01)
        raise TytoTimeout(
            f"no 'Ready' banner from the Tyto stand within {timeout_s:.1f} s "
            "(wrong port, or not a Series 1585?)"
        )

    def identify(self) -> DeviceIdentity:
        return DeviceIdentity(
            kind="tyto-1585", details={"calibration_serial": self.calibration.serial}
        )

    def poll(self) -> TytoReading:
        self.port.write(TytoPoll(self.esc_us).frame())
        deadline = self.clock.now_s() + self.reply_timeout_s
        while True:
            data = self.port.read(max(1, self.port.in_waiting))
            for frame in self._decoder.feed(data):
                return TytoReading.decode(frame.payload)
            if self.clock.now_s() >= deadline:
                raise TytoTimeout(f"no reply to a poll within {self.reply_timeout_s * 1000:.0f} ms")
            if not data:
                self.clock.sleep_s(0.001)

    def read_samples(self) -> list[StandSample]:
        reading = self.poll()
        m = self.calibration.to_si(reading)
        return [
            StandSample(
                time_s=self.clock.now_s(),
                thrust_n=m.thrust_n,
                torque_nm=m.torque_nm,
                voltage_v=m.voltage_v,
                current_a=m.current_a,
                rpm=m.rpm_electrical,
                temperature_c=m.temperatures_c[0],
                vibration_g=m.vibration_g,
                throttle_native=float(self.esc_us) if self.drives_esc else None,
            )
        ]

    def tare(self, service: Callable[[], None] | None = None, polls: int = 20) -> None:
        """Zero the load cells on the mean of ``polls`` readings at rest (``service`` is called
        between polls)."""
        readings = []
        for _ in range(polls):
            readings.append(self.poll())
            if service is not None:
                service()
        mean = replace(
            readings[-1],
            load_thrust=float(np.mean([r.load_thrust for r in readings])),
            load_left=float(np.mean([r.load_left for r in readings])),
            load_right=float(np.mean([r.load_right for r in readings])),
        )
        self.calibration = self.calibration.tared(mean)
        log.info("Tyto stand tared on %d readings", polls)

    def close(self) -> None:
        try:
            self.esc_us = STOP_US
            self.poll()
        except ThrustmapError as exc:
            log.warning("could not send the stop pulse on close: %s", exc)
        finally:
            self.port.close()


class TytoEscOutput(ThrottleOutput):
    """The stand's ESC output as the throttle output (PWM µs), sent with every poll."""

    throttle_scale = SCALES["pwm"]

    def __init__(self, stand: TytoStand, motor: int = 0) -> None:
        self.stand = stand
        self.motor = motor
        stand.drives_esc = True

    def identify(self) -> DeviceIdentity:
        return DeviceIdentity(kind="tyto-1585-esc", motor_protocol="PWM", motor_count=1)

    def set_throttle(self, values: Mapping[int, float]) -> None:
        if set(values) - {self.motor}:
            raise SafetyError(
                f"the stand's ESC output drives one motor ({self.motor}), asked {sorted(values)}"
            )
        us = values.get(self.motor, STOP_US)
        self.stand.esc_us = int(round(min(max(us, STOP_US), 2000)))

    def stop(self) -> None:
        self.stand.esc_us = STOP_US
        self.stand.poll()  # the pulse goes out with the poll

    def verify_stopped(self) -> bool:
        # The stand acknowledges every poll: a reply after the stop poll confirms it left with 1000 µs.
        return self.stand.esc_us == STOP_US and self.stand.poll() is not None

    def read_telemetry(self) -> Telemetry:
        return Telemetry(self.stand.clock.now_s())

    def close(self) -> None:
        pass  # the stand owns the port


# --------------------------------------------------------------------------- calibration file

CALIBRATION_FORMAT = "thrustmap.tyto-calibration"


def calibration_to_dict(cal: TytoCalibration) -> dict[str, Any]:
    """The JSON form of a unit's calibration (``load_calibration`` reads it back)."""

    def cell(c: LoadCell) -> dict[str, float]:
        return {"tare": c.tare, "n_per_count": c.n_per_count}

    out: dict[str, Any] = {
        "format": CALIBRATION_FORMAT,
        "version": 1,
        "serial": cal.serial,
        "thrust": cell(cal.thrust),
        "torque": {
            "arm_length_m": cal.arm_length_m,
            "left": cell(cal.torque_left),
            "right": cell(cal.torque_right),
        },
        "rpm": {
            "electrical_factor": cal.electrical_rpm_factor,
            "optical_factor": cal.optical_rpm_factor,
        },
    }
    if cal.vibration_g_per_count is not None:
        out["vibration_g_per_count"] = cal.vibration_g_per_count
    return out


def _cell(fields: Fields) -> LoadCell:
    n_per_count = fields.number("n_per_count")
    if n_per_count == 0:
        raise fields.error("expected a non-zero number (newtons per count)", "n_per_count")
    return LoadCell(fields.number("tare"), n_per_count)


def calibration_from_dict(data: Any, source: str) -> TytoCalibration:
    """A calibration from its JSON form; errors name ``source`` and the field path."""
    top = Fields(data, source=source)
    top.string("format", choices=(CALIBRATION_FORMAT,))
    top.integer("version", minimum=1, maximum=1)
    torque = top.sub("torque")
    rpm = top.sub("rpm") if top.has("rpm") else Fields({}, source=source, path="rpm")
    return TytoCalibration(
        thrust=_cell(top.sub("thrust")),
        torque_left=_cell(torque.sub("left")),
        torque_right=_cell(torque.sub("right")),
        arm_length_m=torque.number("arm_length_m", minimum=1e-6),
        electrical_rpm_factor=rpm.number("electrical_factor", 1.0),
        optical_rpm_factor=rpm.number("optical_factor", 1.0),
        vibration_g_per_count=top.number("vibration_g_per_count")
        if top.has("vibration_g_per_count")
        else None,
        serial=top.string("serial", ""),
    )


_SIMULATED: dict[str, TytoCalibration] = {}


def register_simulated_calibration(peer: str, cal: TytoCalibration) -> None:
    """The calibration a simulated peer (``sim://<peer>``) was built with: a simulator
    registers it, so opening its URL needs no calibration file (and the rig never imports the
    simulator for it)."""
    _SIMULATED[peer.lower()] = cal


def simulated_calibration(peer: str) -> TytoCalibration | None:
    return _SIMULATED.get(peer.lower())


def load_calibration(path: str | Path) -> TytoCalibration:
    """Read a unit's calibration file (``thrustmap.tyto-calibration`` JSON)."""
    return calibration_from_dict(load_json(path, what="Tyto calibration"), str(path))


def save_calibration(cal: TytoCalibration, path: str | Path) -> None:
    """Write a unit's calibration file atomically."""
    atomic_write_text(path, json.dumps(calibration_to_dict(cal), indent=2) + "\n")
