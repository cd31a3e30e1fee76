"""The top of a file's thrust curve: where thrust stops rising with the command.

A thrust map inverts thrust against throttle, so it needs thrust that rises with the command.
Two things on a real stand break that at the top of a sweep, and both are seen in public
RCbenchmark logs:

- **saturation**: the ESC's output stops at its calibrated end point below the command's top
  (an ESC calibrated to 1840 µs driven to 2000 µs): thrust holds level over the last commands;
- **cut-back**: thrust falls as the command rises (an ESC current or low-voltage limit on a
  sagging cell, a motor losing sync, a propeller slipping).

Past the top, throttle is not a function of thrust: every command from the top up gives about
the same thrust (or less), so those points would pull the inverse map toward commands that buy
nothing. ``past_the_top`` finds them on one file's points; ``select`` leaves them out of the fit
and reports what it found, and a saturation is the map's full-throttle thrust (measured, not
extrapolated: every command above it makes the same thrust).

Rule, on the file's points binned by command (``BIN_PCT``, or coarser for dense ramps; each bin
its median thrust, scaled to one voltage): the top is the highest binned thrust; the knee is the first bin within
``TOP_TOLERANCE`` of it. Points at commands above the knee's bin are past the top when they span
at least ``MIN_SPAN_PCT`` of throttle over at least ``MIN_BINS`` bins (or one bin whose thrust
collapsed below ``COLLAPSE_SHARE`` of the top) AND their thrust rose less
than ``FLAT_SHARE`` of what the curve's slope just below the knee would give over that span, and
their own trend stays under ``FLAT_SHARE`` of the curve's mean slope (one high reading followed
by a curve that keeps rising is a glitch, not a top). A
healthy curve is steepest at its top (thrust grows about as the command squared), so its knee
sits within about 1.5 % of its last command and nothing fires.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from thrustmap.fitting.dataset import FloatArray

#: a bin within this share of the top thrust is at the top
TOP_TOLERANCE = 0.03
#: a fall below the top by more than this share (at the lowest bin past the knee) is a cut-back
CUT_BACK_SHARE = 0.08
#: the commands past the knee must span this much throttle (% of the scale) ...
MIN_SPAN_PCT = 4.0
#: ... over this many command bins ...
MIN_BINS = 2
#: (one bin is enough when its thrust collapsed below this share of the top: a brownout)
COLLAPSE_SHARE = 0.5
#: ... and their thrust rise less than this share of what the slope below the knee would give
FLAT_SHARE = 0.25
#: command bins (% of the scale); a dense ramp is binned coarser (``MAX_BINS`` over its span)
BIN_PCT = 0.5
MAX_BINS = 60
#: points needed before the rule is tried
MIN_POINTS = 5


@dataclass(frozen=True)
class TopCut:
    """Where a file's thrust stopped rising (``kind`` "saturation" or "cut-back") and the
    points past it (``past``: a mask over the points given)."""

    kind: str
    knee_throttle_pct: float  # the first command at the top (the last point the map keeps)
    top_thrust_n: float  # the top binned thrust
    last_throttle_pct: float  # the highest command past the top
    lowest_past_thrust_n: float  # the lowest binned thrust past the knee
    past: np.ndarray

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "knee_throttle_pct": round(self.knee_throttle_pct, 4),
            "top_thrust_n": round(self.top_thrust_n, 6),
            "last_throttle_pct": round(self.last_throttle_pct, 4),
            "lowest_past_thrust_n": round(self.lowest_past_thrust_n, 6),
            "points_dropped": int(self.past.sum()),
        }

    @staticmethod
    def describe(cut: dict[str, Any]) -> str:
        """One line for the fit's warnings, from ``to_dict``'s record."""
        n = int(cut.get("points_dropped", 0))
        what = (
            "the ESC's output saturates below the command's top (its end point is lower "
            "than the command range: recalibrate the ESC's end points, or set the firmware's "
            "output maximum there; the map's full-throttle thrust is its thrust there)"
            if cut.get("kind") == "saturation"
            else "thrust falls as the command rises, more than the voltage explains (an ESC "
            "current or low-voltage limit, a motor losing sync or a slipping propeller)"
        )
        return (
            f"thrust stops rising at {cut['knee_throttle_pct']:.1f} % throttle "
            f"({cut['top_thrust_n']:.4g} N; {cut['lowest_past_thrust_n']:.4g} N at the lowest "
            f"past it, up to {cut['last_throttle_pct']:.1f} %): {what}; {n} point"
            f"{'s' if n != 1 else ''} past the top left out of the fit (--keep-past-top keeps "
            "them)"
        )


def _bins(throttle_pct: FloatArray) -> tuple[np.ndarray, float]:
    span = float(np.ptp(throttle_pct[np.isfinite(throttle_pct)]))
    width = max(BIN_PCT, span / MAX_BINS)
    return np.floor(np.nan_to_num(throttle_pct) / width).astype(np.int64), width


def past_the_top(
    throttle_pct: FloatArray, thrust_n: FloatArray, voltage_v: FloatArray
) -> TopCut | None:
    """The file's top and the points past it (module docstring), or None when thrust rises
    to the last command. Thrust is judged scaled to one voltage, as (B_median / B)², the most
    a voltage can explain: a supply that sags under the top commands (Strawson's 3S runs: 10.8
    V at 81 %, 8.3 V at 100 %, thrust 4.08 -> 3.70 N) lowers thrust for a reason the map models
    in B, and is no top."""
    ok = np.isfinite(throttle_pct) & np.isfinite(thrust_n) & np.isfinite(voltage_v)
    ok &= voltage_v > 0
    if ok.sum() < MIN_POINTS:
        return None
    which, _ = _bins(throttle_pct)
    levels = np.unique(which[ok])
    if len(levels) < MIN_BINS + 2:
        return None
    scaled_n = thrust_n * (float(np.median(voltage_v[ok])) / np.where(ok, voltage_v, 1.0)) ** 2
    centre = np.array([float(np.median(throttle_pct[ok & (which == k)])) for k in levels])
    thrust = np.array([float(np.median(scaled_n[ok & (which == k)])) for k in levels])
    raw = np.array([float(np.median(thrust_n[ok & (which == k)])) for k in levels])
    top = float(thrust.max())
    if not top > 0:
        return None
    knee = int(np.flatnonzero(thrust >= (1.0 - TOP_TOLERANCE) * top)[0])
    after = np.arange(knee + 1, len(levels))
    span = float(centre[-1] - centre[knee])
    collapse = len(after) > 0 and float(thrust[after].min()) < COLLAPSE_SHARE * top
    if (len(after) < MIN_BINS and not collapse) or span < MIN_SPAN_PCT:
        return None
    below = np.flatnonzero(centre <= centre[knee] - span)
    j = int(below[-1]) if len(below) else 0
    if j >= knee:
        return None
    slope = (thrust[knee] - thrust[j]) / (centre[knee] - centre[j])
    rise = float(thrust[after].max() - thrust[knee])
    if not slope > 0 or rise >= FLAT_SHARE * slope * span:
        return None
    if len(after) >= MIN_BINS and knee >= 1:
        # past a true top thrust holds or falls; a curve that keeps rising after one high
        # reading (a load-cell glitch made the "top") is no top: its trend past the knee is
        # judged against the curve's mean slope up to the knee
        mean_slope = (thrust[knee - 1] - thrust[0]) / max(centre[knee - 1] - centre[0], 1e-9)
        trend = float(np.polyfit(centre[after], thrust[after], 1)[0])
        if trend >= FLAT_SHARE * mean_slope:
            return None
    falls = float(thrust[after].min()) < (1.0 - CUT_BACK_SHARE) * top
    kind = "cut-back" if falls else "saturation"
    past = ok & (which > levels[knee])
    top_raw = float(raw[: knee + 1].max())
    return TopCut(
        kind, float(centre[knee]), top_raw, float(centre[-1]), float(raw[after].min()), past
    )
