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
        if self.mass_kg is not None and not self.mass_kg > 0:
            raise ConfigError(f"mass must be positive, got {self.mass_kg} kg")
        if self.rotors is not None and self.rotors < 1:
            raise ConfigError(f"rotor count must be at least 1, got {self.rotors}")
        if not self.rate_hz > 0:
            raise ConfigError(f"resampling rate must be positive, got {self.rate_hz} Hz")
        for name, lo, hi in (  # issue 31: each filter a band it can be (lo < value <= hi)
            ("accel_tol_mps2", 0.0, 9.80665),
            ("tilt_max_deg", 0.0, 90.0),
            ("climb_max_mps", 0.0, 100.0),
            ("settle_s", -1e-12, 3600.0),
            ("min_height_m", -1e-12, 1000.0),
        ):
            value = getattr(self, name)
            if not lo < value <= hi:  # also NaN
                raise ConfigError(f"{option_flag(name)} {value:g}: expected {max(lo, 0):g}..{hi:g}")
        if self.thrust_source not in THRUST_SOURCES:
            raise ConfigError(
                f"thrust source '{self.thrust_source}': expected auto, log, motors or norm"
            )


def option_flag(name: str) -> str:
    """The command-line flag of the DfOptions field ``name`` (``--accel-tol``)."""
    return str(OPTION_FIELDS[name].metadata["option"])


#: the DfOptions fields a command can expose, by field name (in declaration order)
OPTION_FIELDS = {f.name: f for f in fields(DfOptions) if "option" in f.metadata}
