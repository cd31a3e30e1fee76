"""The two lines ``fit`` prints after the map: where it can be trusted (its interval over the
supported region, how it widens outside, how far the benchmark's evidence goes) and where more
data would help most."""

from __future__ import annotations

import math

import numpy as np

from thrustmap.fitting.interval import FloatArray, Interval, Region


def advice(
    interval: Interval | None,
    region: Region,
    over_region: tuple[float, float] | None,
    thrust_n: FloatArray,
    voltage_v: FloatArray,
    physics_voltage: bool,
    few_points: bool = False,
    within_recording: tuple[float, float] | None = None,
) -> tuple[str, str]:
    """Two lines for ``fit``: where the map can be trusted, and where data would help most."""
    t_lo, t_hi = float(thrust_n.min()), float(thrust_n.max())
    b_lo, b_hi = float(voltage_v.min()), float(voltage_v.max())
    if interval is None or over_region is None:
        trust = (
            f"trustworthy only at the data ({region.describe()}); too few points to learn a "
            "prediction interval"
        )
    else:
        lo, hi = over_region
        g = interval.growth_per_span
        if interval.growth_per_reach:
            gr = interval.growth_per_reach
            widen = (
                f"; beyond the thrust reached it widens by ×(1 + {gr:.2f}·√(T/reach - 1)) "
                f"(×{1 + gr * math.sqrt(0.25):.1f} at 1.25× the reach, evidence up to "
                f"{interval.limit_thrust_ratio:g}×), and away from the voltages measured near a "
                f"thrust by ±{interval.voltage_pct_per_log:g} % per unit |ln(B/B_measured)| "
                f"(±{interval.voltage_pct_per_log * math.log(1.1):.1f} % at 10 % off; evidence up "
                f"to {interval.limit_voltage_log:g})"
            )
        elif interval.voltage_pct_per_log:
            widen = (
                f"; beyond the thrust reached it widens by ×{1 + g:.2f} per "
                f"{interval.thrust_unit_n:.3f} N, and away from the voltages measured near a "
                f"thrust by ±{interval.voltage_pct_per_log:g} % per unit |ln(B/B_measured)| "
                f"(±{interval.voltage_pct_per_log * math.log(1.1):.1f} % at 10 % off)"
            )
        else:
            widen = (
                f"; outside it, it widens by ×{1 + g:.2f} per region-size (thrust "
                f"{interval.thrust_unit_n:.3f} N, voltage {interval.voltage_unit_v:.2f} V)"
            )
        rec = (
            f" (±{within_recording[0]:.2f}..{within_recording[1]:.2f} % within this recording; "
            f"a second recording of the rotor adds ±{interval.recording_pct:.2f} % in quadrature)"
            if interval.recording_pct and within_recording is not None
            else ""
        )
        trust = (
            f"trustworthy to ±{lo:.2f}..{hi:.2f} % ({100 * interval.level:.0f} % prediction "
            f"interval) over the supported region{rec}{widen}"
        )
    if physics_voltage and few_points:
        more = (
            f"more data would help most as more throttle levels at several voltages across "
            f"B {b_lo:.2f}..{b_hi:.2f} V: with them the voltage term is fitted, not assumed"
        )
    elif physics_voltage:
        more = (
            f"more data would help most at another battery voltage (e.g. below {0.9 * b_lo:.1f} V "
            "or over a discharge): the voltage scaling now rests on motor physics"
        )
    else:
        ts = np.sort(np.unique(thrust_n))
        gaps = np.diff(ts)
        if len(gaps) and gaps.max() > 0.25 * max(t_hi - t_lo, 1e-9):
            i = int(np.argmax(gaps))
            more = (
                f"more data would help most between T {ts[i]:.3f} and {ts[i + 1]:.3f} N "
                "(the largest gap in thrust)"
            )
        else:
            more = (
                f"more data would help most where the data stop: higher thrust at the lower "
                f"voltages, or outside B {b_lo:.2f}..{b_hi:.2f} V, where the map extrapolates"
            )
    return trust, more
