"""``DfOptions``: the Df extraction's options, declared once.

A field a command exposes carries its command-line option in its metadata (``option``: the
flag, ``help``, ``unit``, ``choices``); ``thrustmap/cli/df_options.py`` makes the click options
from it, defaults included, so a default lives here and nowhere else. The module imports no
numpy (the CLI builds its options from it when it starts), and sits beside the ``df`` package
rather than in it for that reason: importing ``thrustmap.fitting.df`` loads the filters.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

from thrustmap.core.errors import ConfigError

THRUST_SOURCES = ("auto", "log", "motors", "norm")
#: The Df's resampling rate, Hz. Below 0.5 Hz a bin outlasts the 2 s settle margin and the
#: 5 s steady window holds fewer than three bins: a flight of minutes gives a handful of samples
#: or none (0.001 Hz wrote an empty Df). Above 1 kHz no log's accelerometer, attitude and motor
#: outputs together are sampled (Betaflight's fastest motor logging aside, ULog and DataFlash
#: log them at 10-400 Hz): bins would be empty between samples, and the timeline's bin count
#: (span × rate) grows without bound (1e9 Hz: 10^11 bins for a 2-minute flight).
RATE_HZ = (0.5, 1000.0)
#: Each Df filter's band, inclusive (issue 31: a value outside cannot be meant). The lower
#: ends are what a hovering multirotor always exceeds, so a tighter filter keeps nothing and
#: writes an empty Df: its bin-averaged upward acceleration scatters by ~0.05-0.2 m/s² (IMU
#: noise, vibration), its attitude by a degree or more holding position, its climb rate (from
#: a barometer or GNSS) by ~0.05 m/s; the upper ends are g, a quarter turn, no multirotor's
#: climb. 0 s of settling and 0 m of height are "off".
FILTER_BANDS: dict[str, tuple[float, float]] = {
    "accel_tol_mps2": (0.05, 9.80665),
    "tilt_max_deg": (1.0, 90.0),
    "climb_max_mps": (0.05, 100.0),
    "settle_s": (0.0, 3600.0),
    "min_height_m": (0.0, 1000.0),
}
#: Rotors on one vehicle (as ``gamma fit --rotors``).
MAX_ROTORS = 64


def _option(
    default: Any, flag: str, help: str, unit: str = "", choices: tuple[str, ...] = ()
) -> Any:
    """A field with its command-line option: ``flag``, ``help`` and the ``unit`` of its value."""
    meta = {"option": flag, "help": help, "unit": unit, "choices": choices}
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class DfOptions:
    mass_kg: float | None = _option(
        None,
        "--mass-kg",
        "Vehicle take-off mass; F_m = m·a_up.",
        "kg",
    )
    rotors: int | None = _option(
        None,
        "--rotors",
        "Rotor count: sums the first N motor outputs (default: the frame the log or the "
        "vehicle names).",
    )
    rate_hz: float = _option(10.0, "--rate-hz", "Df resampling rate.", "Hz")
    accel_tol_mps2: float = _option(
        1.0, "--accel-tol", "|a_up − g| max (bin-averaged): near hover only.", "m/s²"
    )
    tilt_max_deg: float = _option(15.0, "--tilt-max-deg", "Tilt max.", "deg")
    settle_s: float = _option(
        2.0, "--settle-s", "Margin dropped after takeoff and before landing.", "s"
    )
    max_gap_s: float = 1.0
    steady_tol: float = 0.15  # keep |cmd − running median| ≤ this fraction of the median
    steady_window_s: float = 5.0  # longer than a command dip (≤ 1.5 s seen) twice over
    accel_smooth_s: float = 0.5  # centred running mean of a_up (IMU vibration, aliasing)
    min_height_m: float = _option(  # spool-up, ramp
        0.5,
        "--min-height-m",
        "Airborne only from this height above the takeoff level (0: off).",
        "m",
    )
    climb_max_mps: float = _option(  # takeoff ramp, climbs, descents
        1.0, "--climb-max", "|climb rate| max.", "m/s"
    )
    liftoff_frac: float = 0.9  # airborne from when the command first reaches this × hover
    thrust_source: str = _option(
        "auto",
        "--thrust-source",
        "T_c from the log's newtons, the motor outputs through the map, or the normalised "
        "command through the map.",
        choices=THRUST_SOURCES,
    )
    # supported on the ground: the command below this × hover while a_up stays at g ...
    ground_cmd_frac: float = 0.7
    ground_min_s: float = 2.0  # ... (or the altitude back at the ground level) this long
    height_window_s: float = 5.0  # takeoff level judged this near takeoff, landing level landing
    level_disagree_m: float = 1.0  # warn when takeoff and landing levels differ by more
    rotor_lag_s: float = 0.1  # drop this near a command change larger than steady_tol

    def __post_init__(self) -> None:
        if self.mass_kg is not None and not self.mass_kg > 0:  # also NaN
            raise ConfigError(f"mass must be positive, got {self.mass_kg} kg")
        if self.rotors is not None and not 1 <= self.rotors <= MAX_ROTORS:
            raise ConfigError(f"--rotors {self.rotors}: expected 1..{MAX_ROTORS} rotors")
        lo_hz, hi_hz = RATE_HZ
        if not lo_hz <= self.rate_hz <= hi_hz:  # also NaN
            raise ConfigError(
                f"--rate-hz {self.rate_hz:g}: expected {lo_hz:g}..{hi_hz:g} Hz (the Df's "
                "resampling rate, one bin mean per 1/rate seconds)"
            )
        for name, (lo, hi) in FILTER_BANDS.items():  # each filter a band it can be
            value = getattr(self, name)
            if not lo <= value <= hi:  # also NaN
                unit = OPTION_FIELDS[name].metadata["unit"]
                raise ConfigError(
                    f"{option_flag(name)} {value:g}: expected {lo:g}..{hi:g} {unit}".rstrip()
                )
        if self.thrust_source not in THRUST_SOURCES:
            raise ConfigError(
                f"thrust source '{self.thrust_source}': expected auto, log, motors or norm"
            )


def option_flag(name: str) -> str:
    """The command-line flag of the DfOptions field ``name`` (``--accel-tol``)."""
    return str(OPTION_FIELDS[name].metadata["option"])


#: the DfOptions fields a command can expose, by field name (in declaration order)
OPTION_FIELDS = {f.name: f for f in fields(DfOptions) if "option" in f.metadata}
