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
#: A multirotor's full thrust over its weight: camera and heavy-lift craft ~1.5-3, 5-inch
#: racers ~8-12, the lightest racers up to ~20. A vehicle the map would lift 30 times over hovers
#: at a few % of full thrust, below where its motors spin up: its mass is in another unit (1.5 g
#: typed for 1.5 kg) or the map is another motor's.
MAX_THRUST_TO_WEIGHT = 30.0
#: Interlock thresholds above what a bench can read are no limit at all, a unit mistyped:
#: (the largest value a threshold may take, what the number probably was). Thrust as
#: ``MAX_ROTOR_THRUST_N`` (a stand measures one rotor, or four on one ESC under 4 × 500 N);
#: a stand current of 1000 A is no multirotor ESC's; 200 °C is past every motor's magnets and
#: windings; 200,000 rpm past every propeller's tip speed; 100 g of vibration past every load
#: cell's rating; a watchdog that waits a minute for a silent stand or FC guards nothing.
LIMIT_TOPS: dict[str, tuple[float, str]] = {
    "max_thrust_n": (MAX_ROTOR_THRUST_N, "grams typed as newtons?"),
    "max_current_a": (1000.0, "milliamps typed as amperes?"),
    "max_rpm": (200_000.0, "no propeller turns that fast"),
    "max_temperature_c": (200.0, "°F or kelvin? the limit is in °C"),
    "max_vibration_g": (100.0, "no load cell reads that"),
    "stale_data_s": (60.0, "milliseconds typed as seconds?"),
    "link_timeout_s": (60.0, "milliseconds typed as seconds?"),
}
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
    if hover_n * MAX_THRUST_TO_WEIGHT < hi:
        return (
            f"mass {mass_kg:g} kg on {rotors} rotors needs only {hover_n:.4g} N per rotor to "
            f"hover, 1/{hi / hover_n:.0f} of the {hi:.4g} N the map reaches at {voltage_v:.2f} V "
            f"(thrust-to-weight above {MAX_THRUST_TO_WEIGHT:g} is no multirotor's, which hover "
            "above their motors' spin-up): the mass in another unit (--mass-kg is kg), or the wrong map?"
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


# -- packs and platforms: how many cells a map's voltages are, and where a map may go ------------
#: a LiPo/LiHV cell on a stand, under load up to full charge (V per cell): reads a cell count
CELL_V_RANGE = (3.0, 4.35)
#: the cell counts each export target's platform flies on (a target not named takes any)
TARGET_CELLS: dict[str, tuple[int, int]] = {
    "crazyflie": (1, 1),  # Crazyflie 2.x: one 1S LiPo (bitcraze)
    "crazyflie-cmd": (1, 1),
}


def cells_from_voltage(lo_v: float, hi_v: float) -> int | None:
    """The fewest cells whose per-cell voltage holds ``lo_v..hi_v`` within ``CELL_V_RANGE``
    (a stand's pack is near charged, so the fewest cells is the likely count); None if none."""
    for cells in range(1, 15):
        if hi_v / cells <= CELL_V_RANGE[1] and lo_v / cells >= CELL_V_RANGE[0]:
            return cells
    return None


def target_cells_problem(lo_v: float, hi_v: float, target: str) -> str | None:
    """Why a map measured at ``lo_v..hi_v`` must not be exported to ``target`` (its platform
    flies another cell count), or None when it may (or the count cannot be read)."""
    allowed = TARGET_CELLS.get(target)
    cells = cells_from_voltage(lo_v, hi_v)
    if allowed is None or cells is None or allowed[0] <= cells <= allowed[1]:
        return None
    want = f"{allowed[0]}S" if allowed[0] == allowed[1] else f"{allowed[0]}S..{allowed[1]}S"
    return (
        f"the map was measured on a {cells}S pack ({lo_v:.2f}..{hi_v:.2f} V) but {target} flies "
        f"on {want}: its thrust and throttle would be another motor's; measure this vehicle's "
        "motor on its own pack"
    )


def flight_against_map_pack(
    flown_lo_v: float, flown_hi_v: float, map_lo_v: float, map_hi_v: float
) -> str | None:
    """Why a flight whose battery read ``flown_lo_v..flown_hi_v`` cannot have flown the motor a
    map measured at ``map_lo_v..map_hi_v`` (the two are packs of other cell counts: a 4S quad's
    log through a 6S map has its thrust command read from another motor's map, and the γ fitted
    to that, ~0.6, lies inside the γ band); None when they agree or a count cannot be read."""
    flown = cells_from_voltage(flown_lo_v, flown_hi_v)
    measured = cells_from_voltage(map_lo_v, map_hi_v)
    if flown is None or measured is None or flown == measured:
        return None
    return (
        f"the flight's battery reads {flown}S ({flown_lo_v:.2f}..{flown_hi_v:.2f} V) but the "
        f"map was measured on a {measured}S pack ({map_lo_v:.2f}..{map_hi_v:.2f} V): its thrust "
        "would be another motor's; the wrong map?"
    )


def voltage_against_pack(voltage_v: float, lo_v: float, hi_v: float) -> str | None:
    """Why ``voltage_v`` is not a voltage of the pack a map was measured on (``lo_v..hi_v``)
    but one cell of it, or the whole pack of a per-cell map; None when it is neither."""
    cells = cells_from_voltage(lo_v, hi_v)
    if cells is None:
        return None
    lo_c, hi_c = CELL_V_RANGE
    if cells > 1 and lo_c <= voltage_v <= hi_c and voltage_v < lo_v / 1.5:
        return (
            f"--voltage-v {voltage_v:g} V is one cell of the map's {cells}S pack "
            f"({lo_v:.2f}..{hi_v:.2f} V); give the pack voltage: {voltage_v * cells:.4g} V is "
            f"--voltage-v {voltage_v * cells:.4g}"
        )
    n = round(voltage_v / ((lo_v + hi_v) / 2))
    if cells == 1 and n >= 2 and lo_c <= voltage_v / n <= hi_c:
        return (
            f"--voltage-v {voltage_v:g} V is a {n}S pack but the map's voltages "
            f"({lo_v:.2f}..{hi_v:.2f} V) are one cell (a 1S map, or per-cell voltages of a "
            f"larger pack); give the voltage per cell: --voltage-v {voltage_v / n:.4g}"
        )
    return None


def _another_pack(voltage_v: float, cells: int) -> int | None:
    """The cell count (> 1) whose pack ``voltage_v`` is, when it is no voltage of a ``cells``-cell
    pack (its per-cell voltage outside ``CELL_V_RANGE``); None when it is one, or none fits."""
    lo_c, hi_c = CELL_V_RANGE
    if cells < 2 or lo_c <= voltage_v / cells <= hi_c:
        return None
    for n in range(2, 15):
        if n != cells and lo_c <= voltage_v / n <= hi_c:
            return n
    return None


def other_pack_note(voltage_v: float, lo_v: float, hi_v: float) -> str | None:
    """The note for a voltage that is no voltage of the map's pack but another cell count's
    (16.8 V on a 6S map: 2.80 V per cell, a 4S pack): a prediction there is the motor on that
    pack, from the map's voltage scaling (the cross-voltage use); None otherwise."""
    cells = cells_from_voltage(lo_v, hi_v)
    other = None if cells is None else _another_pack(voltage_v, cells)
    if cells is None or other is None:
        return None
    return (
        f"note: {voltage_v:g} V is {voltage_v / cells:.2f} V per cell of the map's {cells}S pack "
        f"({lo_v:.2f}..{hi_v:.2f} V): a {other}S pack? The answer is this motor on that pack, "
        "from the map's voltage scaling"
    )


def pack_assumed(lo_v: float, hi_v: float) -> str | None:
    """The sentence saying which pack a one-cell map's voltages were read as (None: not a
    one-cell map)."""
    if cells_from_voltage(lo_v, hi_v) != 1:
        return None
    return (
        f"the map's voltages {lo_v:.2f}..{hi_v:.2f} V are one lithium cell: read as a 1S pack "
        "(or the per-cell voltage of a larger pack); --voltage-v is per cell here"
    )


# -- a thrust or voltage column whose unit the file does not name -------------------------------

#: Thrust per electrical watt a multirotor propeller makes at load (the rows above a fifth of
#: the top power), per rotor: 5-inch racers 2-6 gf/W, hover-optimised props up to ~20. A thrust
#: whose unit the header does not name is judged against this: kgf read as newtons gives a
#: tenth of it, grams read as newtons a hundred times it.
TYPICAL_THRUST_PER_WATT_GF = (1.0, 30.0)
#: Thrust units (to N) a unitless column may be in, in the order they are suggested.
THRUST_UNIT_N = {"N": 1.0, "kgf": G0, "gf": G0 / 1000.0, "lbf": 4.4482216152605}
#: Without a current column: the thrust per volt of battery a motor on a pack of 3S or more
#: makes at full throttle (scaled from the top of the log by the square of the throttle) is at
#: least this (2-inch props on 3S ~0.2 N/V, 5-inch ~0.7, 6S 5-inch ~0.5); kgf read as newtons
#: gives a tenth of that (a 5-inch on 3S-6S: 0.05..0.09). A column truly in newtons this weak
#: (a 1.6-inch prop on 3S) names its unit in the header ("Thrust (N)") and is not judged.
MIN_FULL_THRUST_PER_VOLT_N = 0.12
#: ... judged from this pack voltage up (below it, micro motors on 1-2S overlap kgf-as-N) and
#: when the log reaches at least this share of the throttle scale.
JUDGED_FROM_V = 10.0
JUDGED_FROM_PCT = 50.0
#: A voltage column reading one lithium cell (CELL_V) beside a current column: a 1S motor at
#: load makes at most this thrust per watt; a per-cell column of an nS pack makes n times the
#: true figure (a 6S 5-inch reads ~20).
MAX_ONE_CELL_THRUST_PER_WATT_GF = 12.0
#: ... and without a current column, at most this thrust per rotor (1S micro motors ~0.2..2 N).
MAX_ONE_CELL_THRUST_N = 5.0


def thrust_unit_by_power(gf_per_w: float, given: str) -> str | None:
    """The unit a thrust column is in, judged by its thrust per electrical watt (``gf_per_w``,
    computed with the ``given`` unit): None when the given unit gives a typical figure (or no
    unit does), else the unit that does."""
    lo, hi = TYPICAL_THRUST_PER_WATT_GF
    if lo <= gf_per_w <= hi:
        return None
    given_n = THRUST_UNIT_N.get(given, THRUST_UNIT_N.get(given.upper(), 1.0))
    for unit, to_n in THRUST_UNIT_N.items():
        if lo <= gf_per_w * to_n / given_n <= hi:
            return unit
    return None


def thrust_too_small_for_pack(
    top_thrust_n: float, voltage_v: float, top_pct: float, given: str
) -> str | None:
    """Why a thrust column (no current beside it, unit not in its header) is too small for the
    pack and the throttle it reached, naming the likely unit; None when it is not judged or
    fits. ``top_thrust_n``: per rotor, with the ``given`` unit, at ``top_pct`` of throttle."""
    if voltage_v < JUDGED_FROM_V or top_pct < JUDGED_FROM_PCT or top_thrust_n <= 0:
        return None
    full_per_v = top_thrust_n / voltage_v / (top_pct / 100.0) ** 2
    if full_per_v >= MIN_FULL_THRUST_PER_VOLT_N:
        return None
    given_n = THRUST_UNIT_N.get(given, 1.0)
    likely = next(
        (u for u, n in THRUST_UNIT_N.items() if full_per_v * n / given_n >= 0.2 and n > given_n),
        "kgf",
    )
    return (
        f"thrust reaches only {top_thrust_n:.3g} N at {top_pct:.0f} % throttle on a "
        f"{voltage_v:.1f} V pack: {full_per_v:.3f} N per volt at full throttle, where a motor on "
        f"3S or more makes {MIN_FULL_THRUST_PER_VOLT_N:g} N/V or more; is the column in "
        f"{likely} (--thrust-unit {likely})? (a column truly in N: name it 'Thrust (N)')"
    )


def one_cell_voltage(
    voltage_v: float, gf_per_w: float | None, top_thrust_n: float
) -> tuple[bool, str]:
    """A voltage column reading one lithium cell: (refused, why). Beside a current column its
    thrust per watt tells a 1S motor from one cell of a bigger pack; without one, a thrust no
    1S motor makes is refused, and otherwise the pack is taken as 1S, said."""
    lo, hi = CELL_V
    if not lo <= voltage_v <= hi:
        return False, ""
    fix = "give the pack voltage (the per-cell column × the cell count)"
    if gf_per_w is not None and gf_per_w > MAX_ONE_CELL_THRUST_PER_WATT_GF:
        return True, (
            f"voltage reads {voltage_v:.2f} V, one lithium cell, and the thrust per electrical "
            f"watt with it is {gf_per_w:.3g} gf/W at load, more than a 1S motor makes "
            f"({MAX_ONE_CELL_THRUST_PER_WATT_GF:g}): the voltage is per cell of a bigger pack "
            f"(×{gf_per_w / 4.0:.0f} would give 4 gf/W); {fix}"
        )
    if gf_per_w is None and top_thrust_n > MAX_ONE_CELL_THRUST_N:
        return True, (
            f"voltage reads {voltage_v:.2f} V, one lithium cell, but thrust reaches "
            f"{top_thrust_n:.3g} N per rotor, more than a 1S motor makes "
            f"({MAX_ONE_CELL_THRUST_N:g} N): the voltage is per cell of a bigger pack; {fix}"
        )
    return False, (
        f"voltage reads {voltage_v:.2f} V (median), one lithium cell: the pack is taken as 1S "
        "(a per-cell column of a bigger pack would give a map for the wrong voltage: give the "
        "pack voltage)"
    )
