"""Physical checks: the one place that says what a number entering thrustmap may be.

Every quantity that crosses a boundary — a stand log's column, a command-line option, a map
file's coefficients, a γ(B) about to be written — is checked here against physics (and against
the map it meets), so a careless input is refused in one line (exit 2) instead of producing a
confident, wrong answer. Commands and loaders call these
functions; they never carry their own copy of a range. (A flight log's acceleration is
questioned by ``flightlogs.series.question_specific_force``, applied to every reader
where ``fitting.df`` takes it: in g it is converted and said, unphysical it is refused.)

Light on imports (no numpy): the CLI checks options with it before anything heavy is loaded.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from thrustmap.core.errors import ConfigError, DataFormatError

#: standard gravity, m/s²
G0 = 9.80665

#: A battery from 1S under load to 14S fully charged (and a bench supply up to 63 V).
BATTERY_V = (2.5, 63.0)
#: One lithium cell under load (LiPo/Li-ion, down to a deep discharge) up to a full LiHV cell.
CELL_V = (2.5, 4.45)
#: Propellers make at most a few tens of grams of thrust per electrical watt (hover-optimised
#: large props ~20 g/W at low power); 5-inch racers 3-6 g/W. Outside this: a wrong unit (grams
#: read as newtons give ~100 times more).
THRUST_PER_WATT_GF = (0.2, 60.0)
#: Per-rotor thrust no multirotor stand measures (about 200 kgf).
MAX_ROTOR_THRUST_N = 2000.0
#: Thrust per rotor per volt of battery no motor reaches: full-throttle speed grows with the
#: voltage, and the heaviest-lift motors make ~3-7 N per volt (36 kgf on 12S is 7 N/V); 5-inch
#: racers ~1 N/V, a Crazyflie ~0.04 N/V. A gram column read as newtons gives 30-100 N/V.
MAX_THRUST_PER_VOLT_N = 20.0
#: The flight correction γ(B) = T_c / F_m: the stand map and the flight agree within a factor
#: of two (propwash, a different battery, a bent prop); outside it something else is wrong
#: (the mass in the wrong unit, the wrong map or rotor count).
GAMMA_BAND = (0.5, 2.0)
#: Thrust units a column header may name, as the loaders spell them (lower case).
HEADER_THRUST_UNITS = ("n", "kgf", "gf", "g", "kg", "lbf", "ozf")


def finite(value: float, what: str) -> float:
    """``value`` when it is a finite number, else a refusal naming ``what``."""
    if not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"{what}: expected a finite number, got {value}")
    return float(value)


def battery_voltage_v(value: float, what: str = "--voltage-v") -> float:
    """A battery terminal voltage, V: 1S under load to 14S full (``BATTERY_V``). Millivolts
    typed for volts are refused with the value in volts they probably meant."""
    v = finite(value, what)
    lo, hi = BATTERY_V
    if lo * 1000.0 <= v <= hi * 1000.0:
        raise ConfigError(
            f"{what} {v:g}: expected a battery voltage in volts ({lo:g}..{hi:g} V, 1S..14S); "
            f"millivolts? {v / 1000.0:g} V is --voltage-v {v / 1000.0:g}"
        )
    if not lo <= v <= hi:
        raise ConfigError(
            f"{what} {v:g} V is not a battery voltage; expected {lo:g}..{hi:g} V (1S..14S)"
        )
    return v


def rotor_thrust_n(value: float, what: str = "--thrust-n") -> float:
    """A thrust per rotor, N: 0 up to what any multirotor stand measures."""
    t = finite(value, what)
    if t < 0:
        raise ConfigError(f"{what}: expected a value >= 0, got {t:g}")
    if t > MAX_ROTOR_THRUST_N:
        raise ConfigError(
            f"{what} {t:g} N per rotor is beyond any multirotor (> {MAX_ROTOR_THRUST_N:g} N); "
            "grams typed as newtons?"
        )
    return t


def positive(value: float, what: str, unit: str = "") -> float:
    """A finite number > 0."""
    x = finite(value, what)
    if not x > 0:
        raise ConfigError(f"{what}: expected a positive number{' of ' + unit if unit else ''}, "
                          f"got {x:g}")  # fmt: skip
    return x


def gamma_outside_band(gamma: Sequence[float]) -> str | None:
    """Why γ values (over the flown voltages) are not physical, or None when within
    ``GAMMA_BAND``."""
    lo, hi = GAMMA_BAND
    values = [float(g) for g in gamma]
    bad = [g for g in values if not (math.isfinite(g) and lo <= g <= hi)]
    if not bad:
        return None
    worst = max(bad, key=lambda g: abs(math.log(g)) if g > 0 and math.isfinite(g) else math.inf)
    return (
        f"γ(B) reaches {worst:.4g} over the flown voltages; a stand map and a flight agree "
        f"within {lo:g}..{hi:g}: is the mass (--mass-kg, kg), the rotor count or the map right?"
    )


def hover_outside_map(
    mass_kg: float, rotors: int, reachable_n: tuple[float, float], voltage_v: float
) -> str | None:
    """Why a vehicle of ``mass_kg`` on ``rotors`` cannot hover on a map whose thrust at
    ``voltage_v`` spans ``reachable_n`` (0 % .. 100 % throttle), or None when it can."""
    hover_n = mass_kg * G0 / max(rotors, 1)
    lo, hi = reachable_n
    if hover_n > hi:
        return (
            f"mass {mass_kg:g} kg on {rotors} rotors needs {hover_n:.4g} N per rotor to hover; "
            f"the map reaches at most {hi:.4g} N at {voltage_v:.2f} V (100 % throttle): "
            "grams typed as kilograms, or the wrong map?"
        )
    if hover_n < lo:
        return (
            f"mass {mass_kg:g} kg on {rotors} rotors needs only {hover_n:.4g} N per rotor to "
            f"hover, below the map's {lo:.4g} N at 0 % throttle: kilograms typed as grams?"
        )
    return None


def header_thrust_unit(header: str) -> str | None:
    """The thrust unit a column header names, e.g. ``Thrust (gf)`` -> ``gf``, ``thrust_kgf``
    -> ``kgf``; None when it names none."""
    import re

    m = re.search(r"[\(\[]\s*([a-zA-Z]+)\s*[\)\]]\s*$", header.strip()) or re.search(
        r"[_ ]([a-zA-Z]+)$", header.strip()
    )
    if m is None:
        return None
    unit = m.group(1).lower()
    return unit if unit in HEADER_THRUST_UNITS else None


def check_header_unit(header: str, unit: str, *, file: str) -> None:
    """Refuse a thrust column whose header names a different unit than the one given
    (``--col-thrust 'Thrust (gf)' --thrust-unit N``: grams read as newtons)."""
    named = header_thrust_unit(header)
    given = unit.lower()
    same = {"g": "gf", "kg": "kgf"}
    if named is None or same.get(named, named) == same.get(given, given):
        return
    raise DataFormatError(
        f"thrust column '{header}' is in {named} but the thrust unit given is {unit}: "
        f"use --thrust-unit {named}",
        file=file,
    )
