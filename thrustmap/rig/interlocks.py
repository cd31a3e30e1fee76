"""Safety limits ("suspenders"), declared ONCE in the table ``INTERLOCKS``.

Each row names one limit: the ``Limits`` field that holds it, its unit, its default, the CLI
option that sets it, and — for limits checked against every reading — what it reads and which
side of the threshold trips it. Everything else is generated from the table:

- ``Limits`` (the thresholds; its defaults are the table's),
- ``check`` (the first trip of one reading) and ``margins`` (the headroom shown live),
- the options of ``thrustmap sweep`` (``thrustmap.cli.bench.limit_options``).

Adding an interlock is one row here (plus, for a new kind of reading, one ``Reading`` field).
A plan is checked against the throttle ceiling and slew limit before any motor spins
(``check_plan``); the stand and link watchdogs (``stale_data_s``, ``link_timeout_s``) are run by
the runner's loop, and so is the one limit that compares two things over time: thrust must
follow the command (``min_thrust_by_pct``, checked by ``ThrustResponse``).
"""

from __future__ import annotations

import math
import statistics
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from typing import Any, Literal

from thrustmap.core.errors import ConfigError, SafetyError
from thrustmap.core.physical import CELL_V, LIMIT_TOPS
from thrustmap.rig.plans import Plan

#: ``spin``: one short, capped motor test (the CLI's defaults; a sweep uses the table below)
SPIN_MAX_THROTTLE_PCT = 20.0
SPIN_MAX_SECONDS = 10.0


@dataclass(frozen=True)
class Reading:
    """What the runner knows at one instant (None = not measured by this rig)."""

    thrust_n: float | None = None
    current_a: float | None = None
    voltage_v: float | None = None
    rpm: float | None = None
    temperature_c: float | None = None
    vibration_g: float | None = None


@dataclass(frozen=True)
class Interlock:
    """One row of the interlock table (see module)."""

    field: str  # the Limits attribute
    option: str  # the CLI option that sets it
    unit: str
    default: float | int | None
    help: str
    #: "reading": checked on every reading; "plan": checked on the plan before it runs;
    #: "watchdog": a silence the runner's loop times; "setting": feeds another row;
    #: "response": thrust against the command over time (``ThrustResponse``)
    role: Literal["reading", "plan", "watchdog", "setting", "response"]
    name: str = ""  # the trip's name ("thrust"), for role "reading"
    value: Callable[[Reading], float | None] | None = None
    upper: bool = True  # True: trips above the threshold, False: below
    trip_unit: str = ""  # the unit of the reading (default: ``unit``)
    #: the threshold a reading is compared with (default: the field's value)
    threshold: Callable[[Limits], float | None] | None = None
    value_type: type = float

    def limit(self, limits: Limits) -> float | None:
        if self.threshold is not None:
            return self.threshold(limits)
        value = getattr(limits, self.field)
        return None if value is None else float(value)


def _abs_thrust(r: Reading) -> float | None:
    return None if r.thrust_n is None else abs(r.thrust_n)


def _min_voltage(limits: Limits) -> float | None:
    return limits.min_voltage_v


INTERLOCKS: tuple[Interlock, ...] = (
    Interlock(
        "max_thrust_n", "--max-thrust", "N", 20.0, "Stop above this thrust.", "reading",
        "thrust", _abs_thrust,
    ),
    Interlock(
        "max_current_a", "--max-current", "A", 60.0, "Stop above this current.", "reading",
        "current", lambda r: r.current_a,
    ),
    Interlock(
        "min_cell_voltage_v", "--min-cell-voltage", "V per cell", 3.3,
        "Stop below this battery voltage per cell.", "reading", "voltage",
        lambda r: r.voltage_v, upper=False, trip_unit="V", threshold=_min_voltage,
    ),
    Interlock(
        "cells", "--cells", "cells", None,
        "Battery cells for the voltage limit (default: as the FC reports).", "setting",
        value_type=int,
    ),
    Interlock(
        "max_rpm", "--max-rpm", "rpm", 40000.0, "Stop above this speed.", "reading",
        "rpm", lambda r: r.rpm,
    ),
    Interlock(
        "max_temperature_c", "--max-temp", "°C", 90.0,
        "Stop above this motor/ESC temperature.", "reading", "temperature",
        lambda r: r.temperature_c,
    ),
    Interlock(
        "max_vibration_g", "--max-vibration", "g", 8.0, "Stop above this vibration.",
        "reading", "vibration", lambda r: r.vibration_g,
    ),
    Interlock(
        "max_throttle_pct", "--max-throttle", "%", 80.0,
        "Throttle ceiling: a plan above it is refused.", "plan",
    ),
    Interlock(
        "max_slew_pct_s", "--max-slew", "%/s", 100.0,
        "Steps are slewed at this rate; a faster ramp is refused.", "plan",
    ),
    Interlock(
        "stale_data_s", "--stale-s", "s", 0.5, "Stop when the stand is silent this long.",
        "watchdog",
    ),
    Interlock(
        "link_timeout_s", "--link-timeout", "s", 1.0,
        "Stop when the throttle output (FC) is silent this long.", "watchdog",
    ),
    Interlock(
        "min_thrust_by_pct", "--min-thrust-by", "%", 15.0,
        "Stop when thrust has not risen above the stand's noise once the confirmed command "
        "reaches this throttle (or the plan's ceiling, if lower), or falls back to it while "
        "commanded there: a thrown propeller, an unplugged load cell, an ESC that never armed. "
        "0 turns it off.",
        "response", "thrust response",
    ),
)  # fmt: skip
BY_FIELD: dict[str, Interlock] = {i.field: i for i in INTERLOCKS}


def _default(name: str) -> Any:
    return field(default=BY_FIELD[name].default)


@dataclass(frozen=True)
class Limits:
    """The thresholds, one per ``INTERLOCKS`` row (defaults from the table; a test checks that
    the two list the same fields)."""

    max_thrust_n: float = _default("max_thrust_n")
    max_current_a: float = _default("max_current_a")
    min_cell_voltage_v: float = _default("min_cell_voltage_v")
    cells: int | None = _default("cells")
    max_rpm: float = _default("max_rpm")
    max_temperature_c: float = _default("max_temperature_c")
    max_vibration_g: float = _default("max_vibration_g")
    max_throttle_pct: float = _default("max_throttle_pct")
    max_slew_pct_s: float = _default("max_slew_pct_s")
    stale_data_s: float = _default("stale_data_s")
    link_timeout_s: float = _default("link_timeout_s")
    min_thrust_by_pct: float = _default("min_thrust_by_pct")

    def __post_init__(self) -> None:
        """Every threshold a number that can be one: finite and > 0 (``--min-thrust-by`` may
        be 0, which turns it off), a throttle cap at most 100 %, 1..14 cells. A careless
        ``--max-current -5`` is refused naming the option, before anything is opened."""
        for row in INTERLOCKS:
            value = getattr(self, row.field)
            if value is None:
                continue
            off_ok = row.field == "min_thrust_by_pct"
            top = 100.0 if row.field in ("max_throttle_pct", "min_thrust_by_pct") else math.inf
            top = 14 if row.field == "cells" else top
            if not (
                math.isfinite(value) and (value >= 0 if off_ok else value > 0) and value <= top
            ):
                expected = (">= 0" if off_ok else "> 0") + (
                    f" and <= {top:g}" if top < math.inf else ""
                )
                raise ConfigError(
                    f"{row.option} {value:g}: expected a number {expected} {row.unit}".rstrip()
                )
            if row.field in LIMIT_TOPS and value > (bound := LIMIT_TOPS[row.field])[0]:
                raise ConfigError(
                    f"{row.option} {value:g} {row.unit}: at most {bound[0]:g} {row.unit}, above "
                    f"that it is no limit ({bound[1]})"
                )
        lo, hi = CELL_V
        if not lo <= self.min_cell_voltage_v <= hi:
            raise ConfigError(
                f"--min-cell-voltage {self.min_cell_voltage_v:g} V per cell: a lithium cell is "
                f"{lo:g}..{hi:g} V (the pack's voltage? it is per cell)"
            )

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_options(cls, values: dict[str, Any]) -> Limits:
        """From a mapping keyed by field name (the CLI's parsed options); missing or None
        values keep the table's default."""
        return cls(
            **{f.name: values[f.name] for f in fields(cls) if values.get(f.name) is not None}
        )

    @property
    def min_voltage_v(self) -> float | None:
        return None if self.cells is None else self.cells * self.min_cell_voltage_v


@dataclass(frozen=True)
class Trip:
    limit: str
    value: float
    threshold: float
    message: str


def _applicable(limits: Limits, r: Reading) -> list[tuple[Interlock, float, float]]:
    """(row, value, threshold) for every reading interlock that applies to ``r``."""
    out = []
    for row in INTERLOCKS:
        if row.role != "reading" or row.value is None:
            continue
        value, threshold = row.value(r), row.limit(limits)
        if value is not None and threshold is not None:
            out.append((row, value, threshold))
    return out


def check(limits: Limits, reading: Reading) -> Trip | None:
    """The first interlock ``reading`` trips, if any."""
    for row, value, threshold in _applicable(limits, reading):
        if (value > threshold) if row.upper else (value < threshold):
            word = "above" if row.upper else "below"
            unit = row.trip_unit or row.unit
            return Trip(
                row.name,
                value,
                threshold,
                f"{row.name} {value:.2f} {unit} {word} limit {threshold:.2f} {unit}",
            )
    return None


def margins(limits: Limits, reading: Reading) -> dict[str, float]:
    """Headroom to each applicable limit, as a fraction of the limit (1 = far, 0 = at it)."""
    out: dict[str, float] = {}
    for row, value, threshold in _applicable(limits, reading):
        if threshold == 0:
            continue
        out[row.name] = (
            (threshold - value) / threshold if row.upper else (value - threshold) / threshold
        )
    return out


def check_plan(plan: Plan, limits: Limits) -> None:
    """Refuse a plan that would exceed the throttle ceiling or ramp faster than allowed."""
    ceiling, slew_row = BY_FIELD["max_throttle_pct"], BY_FIELD["max_slew_pct_s"]
    if plan.max_throttle_pct > limits.max_throttle_pct:
        raise SafetyError(
            f"plan '{plan.name}' reaches {plan.max_throttle_pct:.1f} % throttle, above the "
            f"{limits.max_throttle_pct:.1f} % ceiling; lower --to or raise {ceiling.option} "
            "explicitly"
        )
    slew = plan.max_ramp_slew_pct_s()
    if slew > limits.max_slew_pct_s:
        raise SafetyError(
            f"plan '{plan.name}' ramps at {slew:.1f} %/s, above the {limits.max_slew_pct_s:.1f} %/s "
            f"slew limit; lengthen the ramp or raise {slew_row.option}"
        )


#: the band around the at-rest thrust that counts as "no thrust": this many standard deviations
#: of the at-rest readings, or their largest excursion (x 1.5), whichever is wider ...
NOISE_SIGMAS = 5.0
NOISE_PEAK_FACTOR = 1.5
#: ... and never narrower than this (a load cell's resolution)
NOISE_FLOOR_N = 0.002
#: how long thrust may stay in the band with the command at or above the threshold: spin-up,
#: an ESC's start-up beeps and the slew of a step, with a margin
RESPONSE_S = 1.5
#: the at-rest readings the noise is measured on: the last this many seconds before the tare
REST_WINDOW_S = 1.0
#: at-rest readings needed to know the noise (fewer: the check is off, and the log says so)
MIN_REST_SAMPLES = 5


class ThrustResponse:
    """Thrust must follow the command (row ``min_thrust_by_pct``).

    Fed the at-rest readings before the plan (their spread is the stand's noise; their mean the
    zero, or 0 once the stand is tared), then every reading of the plan with the command the
    throttle output confirmed. Trips when the confirmed command has stood at or above the
    threshold for ``RESPONSE_S`` without thrust ever leaving the noise band ("did not rise"), or,
    once it had, with thrust back inside the band for ``RESPONSE_S`` ("collapsed")."""

    def __init__(self, limits: Limits, plan_ceiling_pct: float, *, response_s: float = RESPONSE_S):
        chosen = limits.min_thrust_by_pct
        self.threshold_pct = min(chosen, plan_ceiling_pct) if chosen > 0 else 0.0
        self.response_s = response_s
        self._rest: deque[tuple[float, float]] = deque()
        self._zero_n: float | None = None
        self.band_n: float | None = None
        self._above_since: float | None = None  # confirmed command >= threshold since
        self._quiet_since: float | None = None  # thrust inside the band since
        self._rose = False
        self._peak_rpm: float | None = None

    @property
    def enabled(self) -> bool:
        return self.threshold_pct > 0

    def rest_sample(self, time_s: float, thrust_n: float | None) -> None:
        """A reading while the rotor comes to rest (only the last ``REST_WINDOW_S`` are kept:
        a rotor still coasting down at first is not noise)."""
        if thrust_n is None or not math.isfinite(thrust_n):
            return
        self._rest.append((time_s, thrust_n))
        while self._rest and self._rest[0][0] < time_s - REST_WINDOW_S:
            self._rest.popleft()

    def start(self, *, tared: bool) -> None:
        """The plan begins: fix the noise band from the at-rest readings."""
        values = [x for _, x in self._rest]
        if len(values) < MIN_REST_SAMPLES:
            return
        mean = statistics.fmean(values)
        sigma = statistics.pstdev(values)
        peak = max(abs(x - mean) for x in values)
        self.band_n = max(NOISE_SIGMAS * sigma, NOISE_PEAK_FACTOR * peak, NOISE_FLOOR_N)
        self._zero_n = 0.0 if tared else mean

    def update(
        self, now_s: float, confirmed_pct: float, thrust_n: float | None, rpm: float | None
    ) -> Trip | None:
        if not self.enabled or self.band_n is None or self._zero_n is None or thrust_n is None:
            return None
        if rpm is not None and math.isfinite(rpm):
            self._peak_rpm = max(self._peak_rpm or 0.0, abs(rpm))
        if confirmed_pct + 1e-9 < self.threshold_pct:
            self._above_since = self._quiet_since = None
            return None
        if self._above_since is None:
            self._above_since = now_s
        outside = abs(thrust_n - self._zero_n) > self.band_n
        if outside:
            self._rose = True
            self._quiet_since = None
            return None
        if self._quiet_since is None:
            self._quiet_since = max(now_s, self._above_since)
        if now_s - self._quiet_since < self.response_s:
            return None
        return self._trip(confirmed_pct, thrust_n, now_s - self._quiet_since)

    def _trip(self, pct: float, thrust_n: float, quiet_s: float) -> Trip:
        band = self.band_n or 0.0
        if self._rose:
            what = f"thrust collapsed to the stand's noise (|T| <= {band:.3f} N)"
        else:
            what = f"thrust did not rise above the stand's noise (|T| <= {band:.3f} N)"
        rpm = ""
        if self._peak_rpm is not None:
            rpm = (
                f", the motor turns ({self._peak_rpm:.0f} rpm)"
                if self._peak_rpm > 300
                else ", rpm 0"
            )
        return Trip(
            "thrust response",
            abs(thrust_n - (self._zero_n or 0.0)),
            band,
            f"{what} for {quiet_s:.1f} s at {pct:.1f} % confirmed by the throttle output{rpm}: "
            "a thrown propeller, an unplugged load cell or an ESC that never armed? "
            "(--min-thrust-by)",
        )
