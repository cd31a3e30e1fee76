"""What a selection is asked (``Selection``: the range filters and the steady-state
rules' tolerances) and the role each sample of a file played."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Selection:
    throttle_range: tuple[float, float] | None = None  # native units, exclusive
    voltage_range: tuple[float, float] | None = None  # V, exclusive
    thrust_range: tuple[float, float] | None = None  # N (after sign normalisation), exclusive;
    # None keeps 0 < T (points without thrust carry no information about producing it)
    all_samples: bool = False
    plateau_tolerance_pct: float = 0.05  # throttle spread still counted as one level (a command)
    min_plateau_samples: int = 4
    settle_sigmas: float = 3.0
    ramp_lag_s: float = 0.1  # assumed rotor + stand lag for the quasi-static test
    lag_budget_pct: float = 0.25  # lag error allowed on ramps, % throttle
    min_ramp_s: float = 2.0  # a run this long (not a step transition) counts as a ramp to pair
    trend_rel: float = 0.005  # a kept plateau may drift this share of its thrust, or its noise
    stall_fraction: float = 0.1  # a staircase leg under this share of the other (above the
    # load cell's rest reading) had a rotor that was not turning: the pair is dropped
    min_stair_legs: int = 3  # stairs in a leg before up/down pairing is tried
    # A staircase whose stairs last fewer sensor updates than this (median) is a quasi-static
    # ramp: too short to drop a transient and still average, so its legs are paired instead.
    quasi_static_updates: float = 8.0
    quasi_static_lags: float = 10.0  # ... or that last less than this many lag time constants
    pair_voltage_rel: float = 0.05  # up/down readings paired only this close in voltage
    # A staircase (up and back down) whose stairs hold at least this many sensor updates after
    # their transient is read as plateaus on each leg, a point per stair, and the legs'
    # disagreement at equal command is measured (it enters the map's interval)
    leg_plateau_updates: int = 5
    # Zero-command points (rotor at rest: thrust is the load cell's offset) are reported as tare
    # information; True also drops them from the map. Off by default for files whose rest reading
    # is not subtracted as the load cell's zero (a step summary's one rest row): there the point
    # stays. Where the zero is subtracted the rest points are always dropped (they are the zero).
    drop_tare_points: bool = False
    # Points past the top of a file's thrust curve (thrust no longer rising with the command:
    # an ESC saturated below the command's top, or cutting back) are left out (selection.top);
    # True keeps them
    keep_past_top: bool = False

    def to_dict(self) -> dict[str, Any]:
        return {
            "throttle_range": self.throttle_range,
            "voltage_range": self.voltage_range,
            "thrust_range": self.thrust_range,
            "all_samples": self.all_samples,
            "plateau_tolerance_pct": self.plateau_tolerance_pct,
            "settle_sigmas": self.settle_sigmas,
            "lag_budget_pct": self.lag_budget_pct,
            "trend_rel": self.trend_rel,
            "stall_fraction": self.stall_fraction,
            "quasi_static_updates": self.quasi_static_updates,
            "quasi_static_lags": self.quasi_static_lags,
            "pair_voltage_rel": self.pair_voltage_rel,
            "leg_plateau_updates": self.leg_plateau_updates,
            "drop_tare_points": self.drop_tare_points,
            "keep_past_top": self.keep_past_top,
        }


#: per-sample roles (``Points.roles``)
ROLE_OTHER, ROLE_PLATEAU, ROLE_SETTLING, ROLE_STAIR_PAIR, ROLE_RAMP = 0, 1, 2, 3, 4
