"""The common shape every flight-log reader returns.

Each signal keeps its own timestamps (logs mix rates: IMU at 200 Hz, battery at 10 Hz); Df
extraction resamples them onto one timeline. Units and signs are normalised by the reader
(see docs/flight-logs.md):
- ``voltage_v``: battery voltage, V.
- ``accel_up_mps2``: upward specific force, m/s² (≈ +9.81 at rest, level).
- ``thrust_cmd_n``: collective thrust command, N (when the log has it).
- ``thrust_cmd_norm``: collective thrust command normalised 0..1 (when the log has it).
- ``motor_outputs``: per-motor outputs, 2-D (samples × motors) in ``motor_output_scale`` units.
- ``armed`` / ``landed``: 0/1 step signals.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from thrustmap.core.units import ThrottleScale

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Signal:
    time_s: FloatArray  # seconds, monotonic within a log (readers sort/deduplicate)
    values: FloatArray  # shape (n,) or (n, k)
    unit: str
    origin: str  # where it came from, e.g. "battery_status.voltage_v"

    def __post_init__(self) -> None:
        if len(self.time_s) != len(self.values):
            raise ValueError(
                f"{self.origin}: {len(self.time_s)} times vs {len(self.values)} values"
            )

    def __len__(self) -> int:
        return len(self.time_s)

    def interp(self, time_s: FloatArray) -> FloatArray:
        """Linear interpolation onto ``time_s`` (per column for 2-D values)."""
        if self.values.ndim == 1:
            return np.asarray(np.interp(time_s, self.time_s, self.values), dtype=float)
        cols = [
            np.interp(time_s, self.time_s, self.values[:, k]) for k in range(self.values.shape[1])
        ]
        return np.stack(cols, axis=1)

    def hold(self, time_s: FloatArray) -> FloatArray:
        """Zero-order hold onto ``time_s`` (for state signals such as armed/landed)."""
        idx = np.searchsorted(self.time_s, time_s, side="right") - 1
        out = self.values[np.clip(idx, 0, len(self.values) - 1)]
        return np.asarray(np.where(idx < 0, self.values[0], out) if out.ndim == 1 else out, float)


@dataclass
class FlightLog:
    path: str
    format: (
        str  # "ulog", "dataflash", "tlog", "blackbox", "blackbox-csv", "rosbag", "paper-csv", ...
    )
    voltage_v: Signal | None = None
    accel_up_mps2: Signal | None = None
    thrust_cmd_n: Signal | None = None
    thrust_cmd_norm: Signal | None = None
    motor_outputs: Signal | None = None
    motor_output_scale: ThrottleScale | None = None
    armed: Signal | None = None
    landed: Signal | None = None
    hover_thrust_estimate: Signal | None = None  # PX4's hover_thrust_estimate (normalised)
    extras: dict[str, Signal] = field(default_factory=dict)
    metadata: dict[str, Any] = field(default_factory=dict)  # firmware, version, params, ...
    warnings: list[str] = field(default_factory=list)  # e.g. "corrupt tail at byte N, ignored"
    index: int = 0  # which flight within a multi-flight file (blackbox)
