"""The Df extraction's options, its tunable constants and its report types."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from thrustmap.core.errors import ConfigError

G0 = 9.80665
#: an altitude signal whose 5-95 % spread exceeds this while standing on the ground is not used
GROUND_HEIGHT_SPREAD_M = 3.0
#: a range sensor judges height when it is valid for at least this share of the airborne time
RANGE_COVERAGE = 0.8
#: an accelerometer logged slower than this aliases vibration into a_up (the report says so)
MIN_ACCEL_RATE_HZ = 20.0
#: fewer Df samples than this are too few for a γ fit (the report says why)
MIN_DF_SAMPLES = 50
#: a command at or above this fraction of full scale is saturated (thrust limited)
SATURATED_NORM = 0.98
DF_FORMAT = "thrustmap.df"
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class DfOptions:
    mass_kg: float | None = None  # None: use the log's own mass (seed-paper CSV) if it has one
    rotors: int | None = None  # None: number of motor-output columns
    rate_hz: float = 10.0
    accel_tol_mps2: float = 1.0  # keep |a_up − g| ≤ this (bin-averaged)
    tilt_max_deg: float = 15.0
    settle_s: float = 2.0  # dropped after takeoff and before landing
    max_gap_s: float = 1.0
    steady_tol: float = 0.15  # keep |cmd − running median| ≤ this fraction of the median
    steady_window_s: float = 5.0  # longer than a command dip (≤ 1.5 s seen) twice over
    accel_smooth_s: float = 0.5  # centred running mean of a_up (IMU vibration, aliasing)
    min_height_m: float = 0.5  # airborne only this far above the takeoff level (spool-up, ramp)
    climb_max_mps: float = 1.0  # keep |climb rate| ≤ this (takeoff ramp, climbs, descents)
    liftoff_frac: float = 0.9  # airborne from when the command first reaches this × hover
    thrust_source: str = "auto"  # auto | log (thrust_cmd_n) | motors | norm
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
        for name, value, lo, hi in (  # issue 31: each filter a band it can be (lo < value <= hi)
            ("--accel-tol", self.accel_tol_mps2, 0.0, 9.80665),
            ("--tilt-max-deg", self.tilt_max_deg, 0.0, 90.0),
            ("--climb-max", self.climb_max_mps, 0.0, 100.0),
            ("--settle-s", self.settle_s, -1e-12, 3600.0),
            ("--min-height-m", self.min_height_m, -1e-12, 1000.0),
        ):
            if not lo < value <= hi:  # also NaN
                raise ConfigError(f"{name} {value:g}: expected {max(lo, 0):g}..{hi:g}")
        if self.thrust_source not in ("auto", "log", "motors", "norm"):
            raise ConfigError(
                f"thrust source '{self.thrust_source}': expected auto, log, motors or norm"
            )


@dataclass
class FilterStep:
    name: str
    reason: str
    dropped_s: float
    remaining_s: float


@dataclass
class FlightReport:
    flight: str
    path: str
    format: str
    duration_s: float
    kept_s: float
    samples: int
    steps: list[FilterStep] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    voltage_unknown: str | None = None  # why the Df has no battery voltage (None: it has one)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)
