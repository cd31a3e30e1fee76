"""T_c from motor outputs through the stand map, the user's rotor count, and the warnings
for samples outside the map's validity box."""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from thrustmap.core.errors import ConfigError
from thrustmap.core.units import ThrottleScale
from thrustmap.flightlogs.series import FlightLog, FloatArray, Signal

if TYPE_CHECKING:
    from thrustmap.fitting.mapfile import ThrustMap


# -- thrust command from motor outputs -----------------------------------------------------------


def motor_pct_in_map_scale(
    native_pct: FloatArray, log_scale: ThrottleScale, map_scale: ThrottleScale
) -> tuple[FloatArray, str]:
    """Motor outputs (percent of the log's scale) as percent of the map's throttle scale."""
    if log_scale.unit == map_scale.unit:
        native = log_scale.from_pct(native_pct)
        return map_scale.to_pct(native), f"native {log_scale.unit} values through the map's scale"
    return native_pct, (
        f"assumed {log_scale.name} {log_scale.lo:g}..{log_scale.hi:g} spans the map's "
        f"{map_scale.name} {map_scale.lo:g}..{map_scale.hi:g} range"
    )


def thrust_from_motors(
    map_pct: FloatArray, voltage_v: FloatArray, tmap: ThrustMap, rotors: int
) -> FloatArray:
    """Collective T_c (N): per-rotor map forward, summed over rotors. One column = all rotors."""
    per_rotor = tmap.thrust_n(map_pct, voltage_v[:, None], corrected=False)
    if map_pct.shape[1] == 1:
        return np.asarray(per_rotor[:, 0] * rotors, float)
    return np.asarray(per_rotor.sum(axis=1), float)


def _outside(values: FloatArray, lo: float, hi: float, what: str, unit: str) -> list[str]:
    v = values[np.isfinite(values)]
    if not len(v):
        return []
    out = []
    below, above = v < lo, v > hi
    if below.any():
        out.append(
            f"{below.mean():.0%} of the samples have {what} below the map's validity box "
            f"{lo:g}..{hi:g} {unit}, by up to {lo - float(v.min()):.3g} {unit} (extrapolated)"
        )
    if above.any():
        out.append(
            f"{above.mean():.0%} of the samples have {what} above the map's validity box "
            f"{lo:g}..{hi:g} {unit}, by up to {float(v.max()) - hi:.3g} {unit} (extrapolated)"
        )
    return out


def map_extrapolation(
    tmap: ThrustMap, voltage_v: FloatArray, thrust_per_rotor_n: FloatArray, what: str
) -> list[str]:
    """Warnings for Df samples outside the stand map's validity box (voltage, thrust), with how
    far: there the map extrapolates and γ absorbs the map's error."""
    box = tmap.validity
    return _outside(
        np.asarray(voltage_v, float), box.voltage_v.lo, box.voltage_v.hi, "battery voltage", "V"
    ) + _outside(np.asarray(thrust_per_rotor_n, float), box.thrust_n.lo, box.thrust_n.hi, what, "N")


def select_motors(flight: FlightLog, rotors: int | None) -> FlightLog:
    """The flight with exactly ``rotors`` motor-output columns when the user gave a count.

    The readers take the motors from the log's frame (FRAME_CLASS / SERVOn_FUNCTION,
    CA_ROTOR_COUNT, the blackbox motor fields); a count given by the user overrides that: the
    first ``rotors`` of the frame's motors, or of all the log's outputs when it needs more."""
    sig = flight.motor_outputs
    if (
        rotors is None
        or sig is None
        or sig.values.ndim != 2
        or flight.metadata.get("motor_outputs_collective")
    ):
        return flight
    have = sig.values.shape[1]
    if have == rotors:
        return flight
    if rotors < have:
        new = Signal(sig.time_s, sig.values[:, :rotors], sig.unit,
                     f"{sig.origin} (first {rotors} of {have}: --rotors {rotors})")  # fmt: skip
        note = f"--rotors {rotors}: only the first {rotors} of the {have} motor outputs summed"
    else:
        allo = flight.extras.get("outputs_all")
        if allo is None or allo.values.ndim != 2 or allo.values.shape[1] < rotors:
            raise ConfigError(
                f"--rotors {rotors}, but the log has only {have} motor outputs ({sig.origin})"
            )
        new = Signal(allo.time_s, allo.values[:, :rotors], allo.unit,
                     f"{allo.origin.split(',')[0]}..{rotors} (--rotors {rotors})")  # fmt: skip
        note = f"--rotors {rotors}: outputs 1..{rotors} summed, the log's frame has {have} motors"
    return replace(flight, motor_outputs=new, warnings=[*flight.warnings, note])
