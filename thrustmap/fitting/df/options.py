"""The Df extraction's tunable constants and its report types (its options, ``DfOptions``, are
in ``thrustmap.fitting.df_options``)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

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
