"""The contract between simulated peers (byte level) and the physics behind them.

A peer (Betaflight-like MSP responder, PX4/ArduPilot-like MAVLink vehicle, Tyto-like stand,
line stand) owns no physics: it forwards throttle commands to a ``Plant`` and reads its state
back at the current time of the shared clock. ``rig.sim.physics`` provides the real plant;
``ConstantPlant`` here is the plain stand-in for codec-level tests.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol


@dataclass(frozen=True)
class PlantState:
    """What sensors would read at one instant. Per-motor lists are indexed from motor 0."""

    time_s: float
    voltage_v: float  # battery terminal voltage (under load)
    current_a: float  # total battery current
    thrust_n: float  # force on the load cell (the rotor on the stand), pulling = positive
    torque_nm: float  # reaction torque on the load cell
    rpm: list[float] = field(default_factory=list)  # per motor, mechanical RPM
    motor_current_a: list[float] = field(default_factory=list)  # per motor
    temperature_c: list[float] = field(default_factory=list)  # per motor/ESC
    vibration_g: float = 0.0
    motor_thrust_n: list[float] = field(default_factory=list)  # per motor, true (noise-free)


class Plant(Protocol):
    """Motors, ESC and battery. Throttle is a fraction 0..1 of full duty per motor."""

    @property
    def motor_count(self) -> int: ...

    def set_throttle(self, motor: int, fraction: float, time_s: float) -> None:
        """Command motor ``motor`` (0-based) to ``fraction`` of full throttle from ``time_s`` on."""
        ...

    def state(self, time_s: float) -> PlantState:
        """Advance the plant to ``time_s`` (never backwards) and return what sensors read."""
        ...


class ConstantPlant:
    """A plain stand-in: thrust = k·throttle², fixed voltage, no dynamics."""

    def __init__(self, motor_count: int = 4, voltage_v: float = 16.8, max_thrust_n: float = 10.0):
        self._throttle = [0.0] * motor_count
        self._voltage_v = voltage_v
        self._max_thrust_n = max_thrust_n

    @property
    def motor_count(self) -> int:
        return len(self._throttle)

    def set_throttle(self, motor: int, fraction: float, time_s: float) -> None:
        self._throttle[motor] = min(max(fraction, 0.0), 1.0)

    def state(self, time_s: float) -> PlantState:
        thrusts = [self._max_thrust_n * u * u for u in self._throttle]
        rpm = [30000.0 * u for u in self._throttle]
        currents = [30.0 * u**3 for u in self._throttle]
        return PlantState(
            time_s=time_s,
            voltage_v=self._voltage_v - 0.01 * sum(currents),
            current_a=sum(currents),
            thrust_n=thrusts[0],
            torque_nm=0.012 * thrusts[0],
            rpm=rpm,
            motor_current_a=currents,
            temperature_c=[25.0] * self.motor_count,
        )
