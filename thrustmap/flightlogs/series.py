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


def sorted_signal(
    t: FloatArray, v: npt.ArrayLike, unit: str, origin: str, *, state: bool = False
) -> Signal:
    """A signal sorted by time with duplicate timestamps dropped: the first sample of each
    time is kept, or for a ``state`` (events) the last, the state the events leave behind."""
    values = np.asarray(v, dtype=float)
    order = np.argsort(t, kind="stable")
    t, values = t[order], values[order]
    if not len(t):
        return Signal(t, values, unit, origin)
    if state:
        keep = np.concatenate([np.diff(t) > 0, [True]])
    else:
        keep = np.concatenate([[True], np.diff(t) > 0])
    return Signal(t[keep], values[keep], unit, origin)


#: standard gravity, m/s²
G0_MPS2 = 9.80665


def question_specific_force(
    sig: Signal, path: str, *, gravity_removed: bool = False
) -> tuple[Signal, list[str]]:
    """Check that an upward specific force is in m/s²: over a log (ground and flight alike)
    its mean must be near g. A column in g (mean ≈ 1) is converted with a warning; one with
    gravity removed (mean ≈ 0) gets g back when ``gravity_removed`` is allowed; anything else
    (a downward axis, another unit) is refused: a force that cannot be physical is not used."""
    sig, notes = specific_force_unit(sig, gravity_removed=gravity_removed)
    refuse_unphysical_specific_force(sig.values, sig.origin, path)
    return sig, notes


def specific_force_unit(sig: Signal, *, gravity_removed: bool = False) -> tuple[Signal, list[str]]:
    """The unit half of ``question_specific_force``: a column whose mean is ≈ 1 is in g
    (converted, said); with ``gravity_removed`` allowed one whose mean is ≈ 0 gets g0 back.
    Refuses nothing: a reader with a ground rest to calibrate on questions what is left after
    the calibration (``refuse_unphysical_specific_force``)."""
    v = sig.values[np.isfinite(sig.values)]
    if not len(v):
        return sig, []
    mean = float(np.mean(v))
    if 0.7 <= mean <= 1.3:
        return Signal(sig.time_s, sig.values * G0_MPS2, "m/s^2", f"{sig.origin} (g → m/s²)"), [
            f"{sig.origin}: mean upward specific force {mean:.3g}, expected ≈ 9.81 m/s²: "
            "taken as g and converted to m/s²"
        ]
    if gravity_removed and abs(mean) < 0.5:
        return Signal(sig.time_s, sig.values + G0_MPS2, "m/s^2", f"{sig.origin} + g0"), [
            f"{sig.origin} looks gravity-compensated (mean {mean:.2g} m/s²); added g0"
        ]
    return sig, []


#: the mean upward specific force over a flight (m/s²) must lie in this band
SPECIFIC_FORCE_BAND_MPS2 = (7.0, 13.0)


def refuse_unphysical_specific_force(
    values: FloatArray, origin: str, path: str, *, calibrated: str = ""
) -> None:
    """Refuse an upward specific force (m/s²) whose mean over the log is not near g: a
    downward axis, another unit. ``calibrated`` says what was already done to it (a ground-rest
    calibration), so the refusal names what that calibration could not explain."""
    from thrustmap.core.errors import DataFormatError

    v = values[np.isfinite(values)]
    if not len(v):
        return
    mean = float(np.mean(v))
    lo, hi = SPECIFIC_FORCE_BAND_MPS2
    if lo <= mean <= hi:
        return
    hint = " (a downward axis? map it with accel_scale=-1)" if -hi <= mean <= -lo else ""
    after = f" after {calibrated}" if calibrated else ""
    raise DataFormatError(
        f"mean upward specific force {mean:.4g}{after}; expected ≈ 9.81 m/s² over a flight (at "
        f"rest and in hover), or ≈ 1 for a column in g{hint}",
        file=path,
        column=origin,
    )


def nanmedian(x: Any, axis: int | None = None) -> Any:
    """Median ignoring NaN (NaN where nothing is finite), for 1-D data or along ``axis`` 1 of
    2-D data. np.median/np.nanmedian import numpy.ma on first use (~20 ms of a CLI run)."""
    a = np.asarray(x, float)
    if axis is None:
        v = np.sort(a[np.isfinite(a)], axis=None)
        if not len(v):
            return float("nan")
        m = len(v)
        return float(0.5 * (v[(m - 1) // 2] + v[m // 2]))
    if axis != 1 or a.ndim != 2:
        raise ValueError("nanmedian: 1-D data, or 2-D along axis 1")
    s = np.sort(np.where(np.isfinite(a), a, np.inf), axis=1)  # non-finite last
    n = np.isfinite(a).sum(axis=1)
    rows = np.arange(a.shape[0])
    lo = np.clip((n - 1) // 2, 0, max(a.shape[1] - 1, 0))
    hi = np.clip(n // 2, 0, max(a.shape[1] - 1, 0))
    with np.errstate(invalid="ignore"):
        med = 0.5 * (s[rows, lo] + s[rows, hi])
    return np.where(n > 0, med, np.nan)
