"""Safety limits ("suspenders"): each trips on a value outside its band.

``Limits`` holds the thresholds (safe defaults; every one configurable). ``check`` turns one
reading into the first trip, if any, and ``margins`` into the headroom shown live.
A plan is checked against the throttle ceiling and slew limit before any motor spins.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from thrustmap.errors import SafetyError
from thrustmap.rig.plans import Plan


@dataclass(frozen=True)
class Limits:
    max_thrust_n: float = 20.0
    max_current_a: float = 60.0
    min_cell_voltage_v: float = 3.3
    cells: int | None = None  # from the FC when it reports them, else from --cells
    max_rpm: float = 40000.0
    max_temperature_c: float = 90.0
    max_vibration_g: float = 8.0
    max_throttle_pct: float = 80.0
    max_slew_pct_s: float = 100.0  # steps are slewed at this rate, ramps must not exceed it
    stale_data_s: float = 0.5  # no stand sample for this long -> stop
    link_timeout_s: float = 1.0  # no answer from the throttle output for this long -> stop

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @property
    def min_voltage_v(self) -> float | None:
        return None if self.cells is None else self.cells * self.min_cell_voltage_v


@dataclass(frozen=True)
class Trip:
    limit: str
    value: float
    threshold: float
    message: str


@dataclass(frozen=True)
class Reading:
    """What the runner knows at one instant (None = not measured by this rig)."""

    thrust_n: float | None = None
    current_a: float | None = None
    voltage_v: float | None = None
    rpm: float | None = None
    temperature_c: float | None = None
    vibration_g: float | None = None


def _checks(limits: Limits, r: Reading) -> list[tuple[str, float | None, float | None, bool]]:
    """(name, value, threshold, upper?) for every limit that applies."""
    return [
        ("thrust", None if r.thrust_n is None else abs(r.thrust_n), limits.max_thrust_n, True),
        ("current", r.current_a, limits.max_current_a, True),
        ("voltage", r.voltage_v, limits.min_voltage_v, False),
        ("rpm", r.rpm, limits.max_rpm, True),
        ("temperature", r.temperature_c, limits.max_temperature_c, True),
        ("vibration", r.vibration_g, limits.max_vibration_g, True),
    ]


UNITS = {
    "thrust": "N",
    "current": "A",
    "voltage": "V",
    "rpm": "rpm",
    "temperature": "°C",
    "vibration": "g",
}


def check(limits: Limits, reading: Reading) -> Trip | None:
    for name, value, threshold, upper in _checks(limits, reading):
        if value is None or threshold is None:
            continue
        if (value > threshold) if upper else (value < threshold):
            word = "above" if upper else "below"
            return Trip(
                name,
                value,
                threshold,
                f"{name} {value:.2f} {UNITS[name]} {word} limit {threshold:.2f} {UNITS[name]}",
            )
    return None


def margins(limits: Limits, reading: Reading) -> dict[str, float]:
    """Headroom to each applicable limit, as a fraction of the limit (1 = far, 0 = at it)."""
    out: dict[str, float] = {}
    for name, value, threshold, upper in _checks(limits, reading):
        if value is None or threshold is None or threshold == 0:
            continue
        out[name] = (threshold - value) / threshold if upper else (value - threshold) / threshold
    return out


def check_plan(plan: Plan, limits: Limits) -> None:
    """Refuse a plan that would exceed the throttle ceiling or ramp faster than allowed."""
    if plan.max_throttle_pct > limits.max_throttle_pct:
        raise SafetyError(
            f"plan '{plan.name}' reaches {plan.max_throttle_pct:.1f} % throttle, above the "
            f"{limits.max_throttle_pct:.1f} % ceiling; lower --to or raise --max-throttle explicitly"
        )
    slew = plan.max_ramp_slew_pct_s()
    if slew > limits.max_slew_pct_s:
        raise SafetyError(
            f"plan '{plan.name}' ramps at {slew:.1f} %/s, above the {limits.max_slew_pct_s:.1f} %/s "
            "slew limit; lengthen the ramp or raise --max-slew"
        )
