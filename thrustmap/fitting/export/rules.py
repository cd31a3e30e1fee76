"""Firmware rules as data: for each export target and firmware version, every parameter an
export writes (legal range, unit, default, what it changes in flight) and the firmware's own
consistency rules. An export checks its values here before it is written; a value that breaks a
rule refuses the export (``ConfigError``: one line, exit 2), naming the parameter and the rule.

Where each rule was read (the export header cites the firmware and this source):
- ArduCopter 4.x: ArduPilot libraries/AP_Motors/AP_MotorsMulticopter.cpp (parameter table,
  ``arming_checks``, ``check_mot_pwm_params``) and AP_Motors_Thrust_Linearization.cpp. Pre-arm:
  "MOT_SPIN_MIN too high x > 0.3", "MOT_SPIN_ARM > MOT_SPIN_MIN", "Check MOT_PWM_MIN and
  MOT_PWM_MAX" (MOT_PWM_MIN >= 1 and < MOT_PWM_MAX). Voltage compensation is off unless
  MOT_BAT_VOLT_MIN < MOT_BAT_VOLT_MAX. The ArduPilot wiki (set-motor-range) puts MOT_SPIN_MIN
  about 0.03 above MOT_SPIN_ARM: ``ARDUPILOT_SPIN_MARGIN``.
- PX4 v1.14+: THR_MDL_FAC 0..1, MC_BAT_SCALE_EN 0/1, MPC_THR_HOVER 0.1..0.8, and the PWM output
  limits of src/drivers/pwm_out/module.yaml: PWM_MAIN_MINn 800..1400, PWM_MAIN_MAXn 1600..2200
  (before v1.14 one PWM_MAIN_MIN / PWM_MAIN_MAX with the same ranges).
- Betaflight src/main/cli/settings.c and pg/motor.c, pid.c: thrust_linear 0..150,
  motor_output_limit 1..100, max_throttle 750..2250; 4.5: dshot_idle_value 0..2000 and
  min_throttle 750..2250; 4.6 (released as 2025.12) and 2026.6: motor_idle 0..2000, no
  min_throttle (the PWM low end is min_command + motor_idle/10 µs).
- Aerostack2 as2_core PolynomialThrustMap (as loaded by as2_platform_betaflight): throttle in
  whole µs (uint16), min_throttle < max_throttle, thrust min >= 0 and < max.
- C header: this tool's own C99 header; the encoding range LO < HI.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field

from thrustmap.core.errors import ConfigError

#: MOT_SPIN_MIN above MOT_SPIN_ARM (ArduPilot wiki, "Setting motor range": SPIN_ARM + 0.03)
ARDUPILOT_SPIN_MARGIN = 0.03

#: ArduPilot's recommended battery compensation range per cell: MOT_BAT_VOLT_MIN "Recommend 3.3 *
#: cell count", MOT_BAT_VOLT_MAX "Recommend 4.2 * cell count" (libraries/AP_Motors/
#: AP_Motors_Thrust_Linearization.cpp, @Param BAT_V_MIN / BAT_V_MAX)
ARDUPILOT_CELL_V = (3.3, 4.2)
#: PX4 scales the thrust setpoint by BAT1_V_CHARGED / V_cell, constrained to 1..1.3
#: (PX4-Autopilot src/lib/battery/battery.cpp, Battery::computeScale: "Allow at most 30%
#: compensation")
PX4_BATTERY_SCALE_MAX = 1.3

Term = tuple[float, str]  # coefficient x parameter value ("1" is the constant 1)


@dataclass(frozen=True)
class Param:
    name: str  # "{n}" stands for an output number (PWM_MAIN_MIN{n})
    lo: float
    hi: float
    unit: str
    default: float | None
    effect: str
    integer: bool = False
    off: tuple[float, ...] = ()  # values outside lo..hi that mean "disabled" (MOT_BAT_VOLT_MAX 0)

    def problem(self, value: float, shown: str) -> str | None:
        if not math.isfinite(value):
            return f"{shown} is {value}, not a number"
        if value in self.off:
            return None
        if self.integer and value != round(value):
            return f"{shown} = {value:g} must be a whole number"
        if not self.lo <= value <= self.hi:
            unit = f" {self.unit}" if self.unit else ""
            return f"{shown} = {value:g} is outside its range {self.lo:g}..{self.hi:g}{unit}"
        return None


@dataclass(frozen=True)
class Rule:
    """sum(lhs) OP sum(rhs), each side a list of (coefficient, parameter) terms."""

    lhs: tuple[Term, ...]
    op: str  # "<", "<=", ">="
    rhs: tuple[Term, ...]
    message: str  # the firmware's words (or what goes wrong) when the rule is broken
    when: str = ""  # the rule applies only when this parameter is non-zero

    def holds(self, values: Mapping[str, float]) -> bool:
        def side(terms: tuple[Term, ...]) -> float:
            return sum(c * (1.0 if n == "1" else values[n]) for c, n in terms)

        a, b = side(self.lhs), side(self.rhs)
        tol = 1e-9 * max(1.0, abs(a), abs(b))
        if self.op == "<":
            return a < b - tol
        if self.op == "<=":
            return a <= b + tol
        if self.op == ">=":
            return a >= b - tol
        raise ValueError(f"unknown rule operator {self.op}")

    def names(self) -> set[str]:
        return {n for _, n in self.lhs + self.rhs if n != "1"}

    def text(self) -> str:
        def side(terms: tuple[Term, ...]) -> str:
            parts = []
            for c, n in terms:
                if n == "1":
                    parts.append(f"{c:g}")
                else:
                    parts.append(n if c == 1 else f"{c:g}*{n}")
            return " + ".join(parts)

        return f"{side(self.lhs)} {self.op} {side(self.rhs)}"


def _p(name: str) -> tuple[Term, ...]:
    return ((1.0, name),)


def _c(value: float) -> tuple[Term, ...]:
    return ((value, "1"),)


@dataclass(frozen=True)
class Firmware:
    target: str
    title: str  # "ArduCopter 4.x", as the export header names it
    source: str
    params: tuple[Param, ...]
    rules: tuple[Rule, ...] = ()
    notes: tuple[str, ...] = field(default=())

    def param(self, name: str) -> Param:
        for p in self.params:
            if p.name == name or p.name == re.sub(r"\d+$", "{n}", name):
                return p
        raise KeyError(f"{self.title} has no rule for parameter {name}")

    def full(self, written: Mapping[str, float]) -> dict[str, float]:
        """Written values over the firmware defaults (what the vehicle runs after loading)."""
        out = {
            p.name: p.default for p in self.params if p.default is not None and "{n}" not in p.name
        }
        out.update(written)
        return {k: float(v) for k, v in out.items() if v is not None}

    def violations(self, written: Mapping[str, float]) -> list[str]:
        out: list[str] = []
        for name, value in written.items():
            problem = self.param(name).problem(float(value), name)
            if problem is not None:
                out.append(problem)
        values = self.full(written)
        for rule in self.rules:
            if not rule.names() <= set(values):
                continue
            if rule.when and not values.get(rule.when):
                continue
            if not rule.holds(values):
                shown = ", ".join(f"{n} = {values[n]:g}" for n in sorted(rule.names()))
                out.append(f"breaks {rule.text()} ({shown}): {rule.message}")
        return out

    def require(self, written: Mapping[str, float]) -> None:
        """Refuse (one line) an export whose values break a range or rule of this firmware."""
        bad = self.violations(written)
        if bad:
            more = f" (and {len(bad) - 1} more)" if len(bad) > 1 else ""
            raise ConfigError(f"{self.target} export refused for {self.title}: {bad[0]}{more}")

    def changes(self, written: Mapping[str, float]) -> list[str]:
        """One line per written parameter: its value against the firmware default."""
        out: list[str] = []
        for name, value in written.items():
            p = self.param(name)
            unit = f" {p.unit}" if p.unit else ""
            if p.default is None:
                out.append(f"{name} = {value:g}{unit} (no fixed default)")
            elif abs(value - p.default) <= 1e-9 * max(1.0, abs(p.default)):
                out.append(f"{name} = {value:g}{unit} (the default)")
            else:
                out.append(
                    f"{name} = {value:g}{unit} (default {p.default:g}: {value - p.default:+.4g})"
                )
        return out

    def header(self) -> str:
        return f"for {self.title}; ranges and rules read from {self.source}"


# -- ArduPilot ----------------------------------------------------------------------------------
_FRACTION = "of MOT_PWM_MIN..MAX"
ARDUCOPTER_4 = Firmware(
    target="ardupilot",
    title="ArduCopter 4.x (4.5-4.7)",
    source="ArduPilot libraries/AP_Motors/AP_MotorsMulticopter.cpp (arming_checks)",
    params=(
        Param("MOT_THST_EXPO", -1.0, 1.0, "", 0.65,
              "curvature of the thrust curve: how much more output the firmware commands per "
              "unit of thrust at the top than at the bottom"),
        Param("MOT_SPIN_ARM", 0.0, 1.0, _FRACTION, 0.10,
              "motor output when armed on the ground, before take-off"),
        Param("MOT_SPIN_MIN", 0.0, 1.0, _FRACTION, 0.15,
              "lowest motor output in flight: no motor is commanded below it, so it must be "
              "where the motor reliably spins (else a motor stalls in a fast descent)"),
        Param("MOT_SPIN_MAX", 0.0, 1.0, _FRACTION, 0.95,
              "output where thrust saturates: the top of the thrust curve"),
        Param("MOT_PWM_MIN", 0.0, 2000.0, "us", 1000.0,
              "output pulse at 0 (ESC calibration low end)", integer=True),
        Param("MOT_PWM_MAX", 0.0, 2000.0, "us", 2000.0,
              "output pulse at 1 (ESC calibration high end)", integer=True),
        Param("MOT_BAT_VOLT_MAX", 6.0, 53.0, "V", 0.0,
              "voltage where compensation is 1: above it no extra scaling", off=(0.0,)),
        Param("MOT_BAT_VOLT_MIN", 6.0, 42.0, "V", 0.0,
              "voltage below which compensation stops growing (ArduPilot raises it to "
              "0.6 x MOT_BAT_VOLT_MAX)", off=(0.0,)),
        Param("MOT_THST_HOVER", 0.125, 0.6875, "", 0.35,
              "hover thrust as a fraction of full thrust: the altitude controller's starting "
              "point (learned in flight with MOT_HOVER_LEARN)"),
    ),
    rules=(
        Rule(_p("MOT_SPIN_MIN"), "<=", _c(0.3), "PreArm: Motors: MOT_SPIN_MIN too high x > 0.3"),
        Rule(_p("MOT_SPIN_ARM"), "<=", _p("MOT_SPIN_MIN"),
             "PreArm: Motors: MOT_SPIN_ARM > MOT_SPIN_MIN"),
        Rule(_p("MOT_PWM_MIN"), ">=", _c(1.0), "PreArm: Motors: Check MOT_PWM_MIN and MOT_PWM_MAX"),
        Rule(_p("MOT_PWM_MIN"), "<", _p("MOT_PWM_MAX"),
             "PreArm: Motors: Check MOT_PWM_MIN and MOT_PWM_MAX"),
        Rule(_p("MOT_SPIN_MIN"), "<", _p("MOT_SPIN_MAX"),
             "the thrust curve spans MOT_SPIN_MIN..MOT_SPIN_MAX"),
        Rule(_p("MOT_BAT_VOLT_MIN"), "<", _p("MOT_BAT_VOLT_MAX"),
             "voltage compensation is silently off when MOT_BAT_VOLT_MIN >= MOT_BAT_VOLT_MAX",
             when="MOT_BAT_VOLT_MAX"),
    ),
)  # fmt: skip

# -- PX4 ----------------------------------------------------------------------------------------
_PX4_COMMON = (
    Param("THR_MDL_FAC", 0.0, 1.0, "", 0.0,
          "thrust model: 0 treats thrust as linear in the output, 1 as quadratic; the mixer "
          "inverts it so attitude control sees linear thrust"),
    Param("MC_BAT_SCALE_EN", 0.0, 1.0, "", 0.0,
          "scales the thrust setpoint up as the battery sags (BAT1_V_CHARGED / V_now)",
          integer=True),
    Param("MPC_THR_HOVER", 0.1, 0.8, "", 0.5,
          "hover thrust: the position controller's starting point (estimated in flight)"),
)  # fmt: skip
PX4_114 = Firmware(
    target="px4",
    title="PX4 v1.14+",
    source="PX4-Autopilot parameter reference and src/drivers/pwm_out/module.yaml",
    params=_PX4_COMMON + (
        Param("PWM_MAIN_MIN{n}", 800.0, 1400.0, "us", 1000.0,
              "pulse at zero thrust on output n (THR_MDL_FAC is normalised over MIN..MAX)",
              integer=True),
        Param("PWM_MAIN_MAX{n}", 1600.0, 2200.0, "us", 2000.0,
              "pulse at full thrust on output n", integer=True),
    ),
)  # fmt: skip
PX4_113 = Firmware(
    target="px4",
    title="PX4 v1.13 and earlier",
    source="PX4-Autopilot v1.13 parameter reference (PWM_MAIN_MIN/MAX)",
    params=_PX4_COMMON + (
        Param("PWM_MAIN_MIN", 800.0, 1400.0, "us", 1000.0,
              "pulse at zero thrust on the main outputs", integer=True),
        Param("PWM_MAIN_MAX", 1600.0, 2200.0, "us", 2000.0,
              "pulse at full thrust on the main outputs", integer=True),
    ),
    rules=(Rule(_p("PWM_MAIN_MIN"), "<", _p("PWM_MAIN_MAX"), "empty output range"),),
)  # fmt: skip

# -- Betaflight ---------------------------------------------------------------------------------
_BF_LINEAR = Param(
    "thrust_linear", 0.0, 150.0, "%", 0.0,
    "boosts motor output at low throttle (curve out = m*(1 + e*...)): the PID loop sees a more "
    "linear thrust response", integer=True,
)  # fmt: skip
_BF_LIMIT = Param(
    "motor_output_limit", 1.0, 100.0, "%", 100.0,
    "caps the motor output: the top of the output range", integer=True,
)  # fmt: skip
_BF_MAX = Param(
    "max_throttle", 750.0, 2250.0, "us", 2000.0, "PWM pulse at full output", integer=True
)
_BF_IDLE_TEXT = (
    "idle: the lowest output while armed, in 0.01 % of the DShot range (and of the PWM range "
    "above min_command in 4.6+); it must keep the motor spinning"
)
BETAFLIGHT_45 = Firmware(
    target="betaflight",
    title="Betaflight 4.5",
    source="betaflight src/main/cli/settings.c (4.5.5)",
    params=(
        _BF_LINEAR, _BF_LIMIT, _BF_MAX,
        Param("dshot_idle_value", 0.0, 2000.0, "x0.01 %", 550.0, _BF_IDLE_TEXT, integer=True),
        Param("min_throttle", 750.0, 2250.0, "us", 1070.0, "PWM pulse at idle", integer=True),
    ),
    rules=(Rule(_p("min_throttle"), "<", _p("max_throttle"), "empty PWM output range"),),
)  # fmt: skip


def _betaflight_calver(title: str, tag: str) -> Firmware:
    return Firmware(
        target="betaflight",
        title=title,
        source=f"betaflight src/main/cli/settings.c ({tag})",
        params=(
            _BF_LINEAR, _BF_LIMIT, _BF_MAX,
            Param("motor_idle", 0.0, 2000.0, "x0.01 %", 550.0, _BF_IDLE_TEXT, integer=True),
            Param("min_command", 750.0, 2250.0, "us", 1000.0, "PWM pulse when stopped",
                  integer=True),
        ),
        rules=(
            Rule(((1.0, "min_command"), (0.1, "motor_idle")), "<", _p("max_throttle"),
                 "empty PWM output range (low end is min_command + motor_idle/10 us)"),
        ),
    )  # fmt: skip


BETAFLIGHT_46 = _betaflight_calver("Betaflight 4.6 (2025.12)", "2025.12.5")
BETAFLIGHT_2026 = _betaflight_calver("Betaflight 2026.6", "2026.6.1")

# -- Aerostack2, C header -----------------------------------------------------------------------
AEROSTACK2 = Firmware(
    target="aerostack2",
    title="Aerostack2 (as2_core PolynomialThrustMap, as2_platform_betaflight)",
    source="aerostack2 as2_core polynomial_thrust_map and as2_platform_betaflight",
    params=(
        Param("min_throttle", 0.0, 65535.0, "platform units", None,
              "command at the low end: as2 clamps its result here"),
        Param("max_throttle", 0.0, 65535.0, "platform units", None,
              "command at the top: as2 clamps its result here"),
        Param("thrust_min_n", 0.0, math.inf, "N", None, "lowest collective thrust commanded"),
        Param("thrust_max_n", 0.0, math.inf, "N", None, "highest collective thrust commanded"),
    ),
    rules=(
        Rule(_p("min_throttle"), "<", _p("max_throttle"), "empty throttle range"),
        Rule(_p("thrust_min_n"), "<", _p("thrust_max_n"), "empty thrust range"),
    ),
)  # fmt: skip
C_HEADER = Firmware(
    target="c-header",
    title="C99 (thrustmap generated header)",
    source="this tool's header template",
    params=(
        Param("range_lo", -math.inf, math.inf, "encoding units", None, "output at 0 %"),
        Param("range_hi", -math.inf, math.inf, "encoding units", None, "output at 100 %"),
    ),
    rules=(Rule(_p("range_lo"), "<", _p("range_hi"), "empty output range"),),
)  # fmt: skip


def _version(text: str, option: str = "--firmware") -> tuple[int, ...]:
    try:
        return tuple(int(p) for p in text.strip().lstrip("vV").split("."))
    except ValueError:
        raise ConfigError(
            f"{option}: expected a version like 4.6 or 2026.6, got '{text}'"
        ) from None


def ardupilot_rules(firmware: str | None) -> Firmware:
    if firmware is not None and _version(firmware)[:1] != (4,):
        raise ConfigError(
            f"--firmware {firmware}: the ArduPilot export knows the rules of ArduCopter 4.x only"
        )
    return ARDUCOPTER_4


def px4_rules(firmware: str | None) -> Firmware:
    if firmware is None:
        return PX4_114
    v = _version(firmware)
    if v[:1] != (1,) or v[:2] < (1, 12):
        raise ConfigError(
            f"--firmware {firmware}: the PX4 export knows the rules of PX4 v1.12 and later"
        )
    return PX4_114 if v[:2] >= (1, 14) else PX4_113


def betaflight_rules(firmware: str) -> Firmware:
    v = _version(firmware)
    if v[:2] == (4, 5):
        return BETAFLIGHT_45
    if v[:2] in ((4, 6), (2025, 12)):
        return BETAFLIGHT_46
    if v[:2] == (2026, 6):
        return BETAFLIGHT_2026
    raise ConfigError(
        f"--firmware {firmware}: the Betaflight export knows the rules of 4.5, 4.6 (2025.12) "
        "and 2026.6; check the names and ranges of yours before adding it"
    )
