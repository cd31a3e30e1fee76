"""The two small interfaces every device driver implements: a throttle output and a stand.

Drivers talk to a pyserial-like transport (or a pymavlink connection) and never know whether
the peer is real, simulated (``sim://``) or a replayed transcript (``replay://``).

Safety contract of ``ThrottleOutput``: used as a context manager, its exit ALWAYS commands
stop and verifies it where the protocol allows — on normal exit, on any exception, on
KeyboardInterrupt and on SIGTERM (see ``rig.sigterm.terminate_as_exception``).
"""

from __future__ import annotations

import logging
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import TracebackType

from thrustmap.core.errors import SafetyError
from thrustmap.core.units import ThrottleScale

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DeviceIdentity:
    """What is connected, as far as the device says."""

    kind: str  # "betaflight", "inav", "px4", "ardupilot", "tyto-1585", "line-stand", ...
    firmware_version: str = ""
    board: str = ""
    motor_protocol: str = ""  # "PWM", "ONESHOT125", "DSHOT600", ... (FCs)
    motor_count: int = 0
    battery_cells: int | None = None
    details: dict[str, str] = field(default_factory=dict)

    def to_dict(self) -> dict[str, object]:
        return {
            "kind": self.kind,
            "firmware_version": self.firmware_version,
            "board": self.board,
            "motor_protocol": self.motor_protocol,
            "motor_count": self.motor_count,
            "battery_cells": self.battery_cells,
            "details": dict(self.details),
        }


@dataclass(frozen=True)
class Telemetry:
    """One reading of what an FC (or ESC telemetry) reports. Missing values are None."""

    time_s: float
    voltage_v: float | None = None
    current_a: float | None = None
    rpm: tuple[float, ...] | None = None
    temperature_c: tuple[float, ...] | None = None


@dataclass(frozen=True)
class StandSample:
    """One timestamped stand reading, SI units, pulling thrust positive."""

    time_s: float
    thrust_n: float
    torque_nm: float | None = None
    voltage_v: float | None = None
    current_a: float | None = None
    rpm: float | None = None
    temperature_c: float | None = None
    vibration_g: float | None = None
    throttle_native: float | None = None  # what the stand itself sent to the ESC, if it drives it


class DeviceAbort(SafetyError):
    """The device itself stopped the run (a stand core's cutoff): the runner aborts naming it
    (exit 1), stops and verifies as on every way out, and never clears what the device raised."""


class StopNotVerified(RuntimeError):
    """The stop command was sent but the device did not confirm motors at rest."""


class ThrottleOutput(ABC):
    """Something that commands motor throttle: an FC over MSP/MAVLink, or a stand's ESC output."""

    #: the native scale of ``set_throttle`` values (µs for PWM-like, MSP's 1000..2000, ...)
    throttle_scale: ThrottleScale

    @abstractmethod
    def identify(self) -> DeviceIdentity: ...

    @abstractmethod
    def set_throttle(self, values: Mapping[int, float]) -> None:
        """Command motors (0-based index) to native throttle values; others stay stopped."""

    def keepalive(self) -> None:  # noqa: B027 - optional hook
        """Re-send the current command where the protocol times out (MAVLink motor tests)."""

    @abstractmethod
    def stop(self) -> None:
        """Command every motor to stop now."""

    @abstractmethod
    def verify_stopped(self) -> bool:
        """Ask the device whether all motors are at rest (True when confirmed)."""

    @abstractmethod
    def read_telemetry(self) -> Telemetry: ...

    @abstractmethod
    def close(self) -> None: ...

    def stop_and_verify(self, attempts: int = 3, *, alarm: bool = True) -> bool:
        """Send stop, confirm it; retry. Never raises: this runs on every way out.

        ``alarm``: raise the CRITICAL alarm when the stop cannot be verified; a caller that
        keeps retrying (the runner's stop loop) passes False and raises it once, at its end."""
        for attempt in range(1, attempts + 1):
            try:
                self.stop()
                if self.verify_stopped():
                    log.info("motors stopped (verified, attempt %d)", attempt)
                    return True
                log.warning("stop not confirmed (attempt %d of %d)", attempt, attempts)
            except Exception as exc:  # the link may be gone; keep trying, then report
                log.error("stop attempt %d failed: %s", attempt, exc)
        if alarm:
            log.critical("COULD NOT VERIFY MOTOR STOP - disconnect the battery now")
        return False

    def __enter__(self) -> ThrottleOutput:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        from thrustmap.rig.sigterm import interrupts_deferred

        try:
            with interrupts_deferred():  # a second Ctrl-C must not cut the stop short
                self.stop_and_verify()
        finally:
            self.close()


class Stand(ABC):
    """A thrust stand: streams timestamped samples; some also drive the ESC themselves."""

    @abstractmethod
    def identify(self) -> DeviceIdentity: ...

    @abstractmethod
    def read_samples(self) -> list[StandSample]:
        """Poll the stand and return the samples received since the last call (maybe none)."""

    @abstractmethod
    def tare(self, service: Callable[[], None] | None = None) -> None:
        """Zero the load cells with the motor at rest. ``service`` is called between readings
        so the caller keeps its other links alive while the stand is tared."""

    @abstractmethod
    def close(self) -> None: ...

    def __enter__(self) -> Stand:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
