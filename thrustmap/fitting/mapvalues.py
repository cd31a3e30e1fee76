"""One number per question: the values every export, the report and ``predict`` take from a map.

The thrust at full throttle, the hover throttle for a given thrust and the spin-up point are
computed here ONCE, each as a :class:`MapValue` (the value, its 95 % interval, and whether it
lies outside the map's supported region), so a PX4, ArduPilot, Betaflight or Crazyflie export,
the C header, the encoding YAML, the report and ``predict`` write the same number, each in its
own units, and each says when it is extrapolated.

Intervals. The map's prediction interval is in throttle (% of its scale), at a thrust T:
throttle = f(T, B) ± h(T, B). The thrust made at a throttle p is therefore every T with
|f(T, B) − p| ≤ h(T, B): from the T where f + h = p up to the T where f − h = p (``inf`` when
the interval grows faster than the map rises, so no upper bound can be given). A throttle for a
thrust is f(T, B) ± h(T, B) directly. The spin-up point is a threshold measured on the stand, not
a prediction: it has no interval, and says so.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from thrustmap.core.errors import FitError
from thrustmap.fitting.mapfile import ThrustMap
from thrustmap.fitting.spinup import SpinUp

#: bisection steps for a thrust (60 halve the bracket below 1e-15 of it)
_BISECT_STEPS = 80
#: how far above the full-throttle thrust the interval's upper end is searched (x the value)
_SEARCH_FACTOR = 16.0
#: steps of the scan for the interval's upper end (the first crossing is the bound)
_SCAN_POINTS = 400


@dataclass(frozen=True)
class MapValue:
    """One value the map answers: ``value`` in ``unit`` with its 95 % interval ``lo..hi``
    (None: the map has no interval, or the value is measured, not predicted; ``hi`` may be
    ``inf``) at ``voltage_v``, and whether it lies outside the supported region."""

    key: str  # "full_throttle_thrust_n", "hover_throttle_pct", "spin_up_throttle_pct"
    name: str  # "full-throttle thrust", as a header names it
    value: float
    unit: str  # "N" or "%"
    lo: float | None
    hi: float | None
    voltage_v: float
    thrust_n: float  # the (T, B) point the value is at
    throttle_pct: float
    extrapolated: bool  # outside the supported region (where the map's data are)
    #: how far outside, in units of the supported region's thrust span (0 inside)
    distance: float = 0.0
    #: what the data reached at this voltage (T lo..hi, N), for the sentence
    reach_n: tuple[float, float] | None = None
    note: str = ""
    level: float = 0.95
    #: why the value lies beyond what the extrapolation benchmark has evidence for (None:
    #: within it); its interval there rests on the growth's extrapolation (docs/intervals.md)
    beyond_evidence: str | None = None
    #: what the value rests on when that is not the map at the value's own throttle (the ESC's
    #: saturation: the full-throttle thrust is the map's thrust where the output saturated)
    basis: str = ""

    def interval_text(self, convert: Callable[[float], float] | None = None, unit: str = "") -> str:
        """'95 % interval 17.9..22.3 N' (in ``convert``'s units when given)."""
        if self.lo is None or self.hi is None:
            return "no interval (" + (self.note or "the map has none") + ")"
        c = convert or (lambda x: x)
        u = unit or self.unit
        hi = "unbounded" if not math.isfinite(self.hi) else f"{c(self.hi):.4g}"
        return f"{100 * self.level:.0f} % interval {c(self.lo):.4g}..{hi} {u}"

    def line(self, convert: Callable[[float], float] | None = None, unit: str = "") -> str:
        """One header line: name, value, interval, and where it stands."""
        c = convert or (lambda x: x)
        u = unit or self.unit
        where = "inside the supported region"
        if self.extrapolated:
            reach = (
                f"; the data reach {self.reach_n[0]:.4g}..{self.reach_n[1]:.4g} N there"
                if self.reach_n is not None
                else ""
            )
            where = (
                f"EXTRAPOLATED: outside the supported region ({self.distance:.2f} region "
                f"spans beyond{reach})"
            )
            if self.beyond_evidence:
                where += (
                    f"; BEYOND THE EVIDENCE ({self.beyond_evidence}): the interval there is the "
                    "growth extrapolated, not measured"
                )
        basis = f"; {self.basis}" if self.basis else ""
        return (
            f"{self.name} at {self.voltage_v:.4g} V: {c(self.value):.4g} {u}, "
            f"{self.interval_text(convert, unit)}; {where}{basis}"
        )

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["reach_n"] = list(self.reach_n) if self.reach_n is not None else None
        if d["hi"] is not None and not math.isfinite(d["hi"]):
            d["hi"] = None
            d["hi_unbounded"] = True
        return d


@dataclass(frozen=True)
class MapValues:
    """The values an export writes, computed once (:func:`map_values`)."""

    voltage_v: float
    #: None: the map cannot say (it does not reach the throttle near its data; ``unknown``)
    full_throttle: MapValue | None
    hover: MapValue | None = None
    spin_up: MapValue | None = None
    extra: tuple[MapValue, ...] = field(default=())
    #: why a value is None, one sentence each
    unknown: tuple[str, ...] = field(default=())

    def all(self) -> list[MapValue]:
        out = [self.full_throttle, self.hover, self.spin_up, *self.extra]
        return [v for v in out if v is not None]

    def outside(self) -> list[MapValue]:
        return [v for v in self.all() if v.extrapolated]

    def to_dict(self) -> dict[str, Any]:
        return {v.key: v.to_dict() for v in self.all()}


@dataclass(frozen=True)
class _Place:
    """Where a value's (T, B) stands: outside the supported region, how far (thrust spans),
    the reach at B (N), and why it is beyond the benchmark's evidence (None: within it)."""

    outside: bool
    distance: float
    reach_n: tuple[float, float]
    beyond_evidence: str | None


def _where(tmap: ThrustMap, thrust_n: float, voltage_v: float) -> _Place:
    """Where (T, B) stands, as ``predict`` says it (``ThrustMap.standing``)."""
    t_model = float(tmap.model_thrust(thrust_n, voltage_v))
    region = tmap.supported_region()
    st = tmap.standing(thrust_n, voltage_v)
    dist = float(region.distance(t_model, voltage_v, region.thrust_span_n, region.voltage_unit_v))
    g = t_model / thrust_n if thrust_n > 0 else 1.0  # γ(B): the region is in bench thrust
    lo, hi = (float(x) / g for x in region.thrust_range(voltage_v))
    return _Place(st.extrapolated, dist, (lo, hi), st.beyond_evidence)


def _solve_thrust(fn: Callable[[float], float], lo: float, hi: float) -> float:
    """The T in lo..hi where the increasing ``fn`` crosses 0 (bisection)."""
    for _ in range(_BISECT_STEPS):
        mid = 0.5 * (lo + hi)
        if fn(mid) < 0.0:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def _first_crossing(fn: Callable[[float], float], lo: float, top: float) -> float:
    """The first T above ``lo`` (up to ``top``) where ``fn`` turns non-negative, ``inf`` when
    it never does (the interval then grows faster than the map rises: no upper bound)."""
    grid = np.linspace(lo, top, _SCAN_POINTS)
    for a, b in zip(grid[:-1], grid[1:], strict=True):
        if fn(float(b)) >= 0.0:
            return _solve_thrust(fn, float(a), float(b))
    return math.inf


def _pct(tmap: ThrustMap, thrust_n: float, voltage_v: float) -> float:
    return float(tmap.throttle_pct(thrust_n, voltage_v))


def _half(tmap: ThrustMap, thrust_n: float, voltage_v: float) -> float | None:
    h = tmap.interval_pct(thrust_n, voltage_v)
    return None if h is None else float(h)


def thrust_at(tmap: ThrustMap, throttle_pct: float, voltage_v: float) -> float:
    """The thrust per rotor (N) the map gives at ``throttle_pct`` and ``voltage_v`` (γ applied):
    the first T from 0 up where f(T, B) reaches the throttle (a polynomial map may fold back
    far outside its data; the first crossing is the one the data lead to)."""
    if _pct(tmap, 0.0, voltage_v) >= throttle_pct:
        return 0.0
    top = max(tmap.validity.thrust_n.hi, 1e-6) * _SEARCH_FACTOR
    t = _first_crossing(lambda x: _pct(tmap, x, voltage_v) - throttle_pct, 0.0, top)
    if not math.isfinite(t):
        raise FitError(
            f"the map does not reach {throttle_pct:.4g} % throttle at {voltage_v:.4g} V below "
            f"{top:.4g} N ({_SEARCH_FACTOR:g} x its top thrust): it cannot say the thrust there"
        )
    return t


def thrust_value(
    tmap: ThrustMap, throttle_pct: float, voltage_v: float, *, key: str, name: str
) -> MapValue:
    """The thrust at a throttle, with its interval in N (module docstring) and its place."""
    t = thrust_at(tmap, throttle_pct, voltage_v)
    lo: float | None = None
    hi: float | None = None
    if _half(tmap, t, voltage_v) is not None:

        def upper(x: float) -> float:  # f + h - p: crosses 0 at the interval's low end
            return _pct(tmap, x, voltage_v) + (_half(tmap, x, voltage_v) or 0.0) - throttle_pct

        def lower(x: float) -> float:  # f - h - p: crosses 0 at the interval's high end
            return _pct(tmap, x, voltage_v) - (_half(tmap, x, voltage_v) or 0.0) - throttle_pct

        lo = 0.0 if upper(0.0) >= 0.0 else _solve_thrust(upper, 0.0, t)
        hi = _first_crossing(lower, t, max(t, 1e-6) * _SEARCH_FACTOR)
    at = _where(tmap, t, voltage_v)
    return MapValue(
        key, name, t, "N", lo, hi, voltage_v, t, throttle_pct, at.outside, at.distance,
        at.reach_n, note=f"the map's thrust at {throttle_pct:.4g} % throttle",
        beyond_evidence=at.beyond_evidence,
    )  # fmt: skip


def throttle_value(
    tmap: ThrustMap, thrust_n: float, voltage_v: float, *, key: str, name: str
) -> MapValue:
    """The throttle (% of the map's scale) for a thrust, ± the map's interval there."""
    p = _pct(tmap, thrust_n, voltage_v)
    h = _half(tmap, thrust_n, voltage_v)
    at = _where(tmap, thrust_n, voltage_v)
    return MapValue(
        key, name, p, "%", None if h is None else p - h, None if h is None else p + h,
        voltage_v, thrust_n, p, at.outside, at.distance, at.reach_n,
        note=f"the map's throttle for {thrust_n:.4g} N", beyond_evidence=at.beyond_evidence,
    )  # fmt: skip


def spin_up_value(tmap: ThrustMap, voltage_v: float) -> MapValue | None:
    """The measured spin-up (% of the map's scale), None when the stand data cannot tell."""
    block = SpinUp.from_dict(tmap.spin_up) if tmap.spin_up else None
    if block is None or block.throttle_pct is None:
        return None
    p = float(block.throttle_pct)
    return MapValue(
        "spin_up_throttle_pct", "spin-up point", p, "%", None, None, voltage_v, 0.0, p, False,
        note=f"measured on the stand ({block.signal}), a threshold, not a prediction",
    )  # fmt: skip


def saturation_pct(tmap: ThrustMap) -> float | None:
    """The command (% of the map's scale) above which the stand saw the ESC's output saturate
    (None: thrust rose to the top command): every command above it makes the thrust there."""
    sat = tmap.saturation.get("throttle_pct") if tmap.saturation else None
    return None if sat is None else float(sat)


def saturation_note(tmap: ThrustMap, pct: float) -> str:
    """The sentence for a command at or above the saturation."""
    sat = saturation_pct(tmap)
    if sat is None:
        return ""
    native = pct_to_native(tmap)
    return (
        f"the ESC's output saturated at {sat:.4g} % ({native(sat):.5g} "
        f"{tmap.throttle_scale.unit_label}) on the stand: every command above gives the thrust "
        "there"
    )


def thrust_at_command(
    tmap: ThrustMap, throttle_pct: float, voltage_v: float, *, key: str, name: str
) -> MapValue:
    """The thrust a command makes: the map's thrust there, or, above the command where the
    stand saw the ESC's output saturate (the map's ``saturation``), the map's thrust at the
    saturation (every command above it makes that thrust: measured, not the curve carried on)."""
    sat = saturation_pct(tmap)
    if sat is None or sat >= throttle_pct:
        return thrust_value(tmap, throttle_pct, voltage_v, key=key, name=name)
    basis = saturation_note(tmap, throttle_pct)
    at = thrust_value(tmap, sat, voltage_v, key=key, name=name)
    return replace(at, note=basis, basis=basis)


def full_throttle_value(tmap: ThrustMap, full_pct: float, voltage_v: float) -> MapValue:
    """The thrust at ``full_pct`` (the top of an export's output range)."""
    return thrust_at_command(
        tmap, full_pct, voltage_v, key="full_throttle_thrust_n", name="full-throttle thrust"
    )


def map_values(
    tmap: ThrustMap,
    voltage_v: float | None = None,
    *,
    full_pct: float = 100.0,
    hover_thrust_n: float | None = None,
) -> MapValues:
    """The full-throttle thrust (at ``full_pct`` of the map's scale, the top of an export's
    output range), the hover throttle (for ``hover_thrust_n`` per rotor when given) and the
    spin-up point, at ``voltage_v`` (default: the top of the map's voltage box, where every
    export fits its voltage-free curve)."""
    b = float(tmap.validity.voltage_v.hi if voltage_v is None else voltage_v)
    unknown: list[str] = []
    full = None
    try:
        full = full_throttle_value(tmap, full_pct, b)
    except FitError as exc:
        unknown.append(f"full-throttle thrust: {exc}")
    hover = None
    if hover_thrust_n is not None:
        hover = throttle_value(
            tmap, hover_thrust_n, b, key="hover_throttle_pct", name="hover throttle"
        )
    return MapValues(b, full, hover, spin_up_value(tmap, b), (), tuple(unknown))


def fraction_of(value: float, full: MapValue) -> tuple[float, float | None, float | None]:
    """``value`` N as a fraction of the full-throttle thrust, with the interval that the full
    thrust's interval gives it (the firmware's hover-thrust parameters)."""
    frac = value / full.value
    lo = None if full.hi is None else (0.0 if not math.isfinite(full.hi) else value / full.hi)
    hi = None if full.lo is None else (math.inf if full.lo <= 0 else value / full.lo)
    return frac, lo, hi


def pct_to_native(tmap: ThrustMap) -> Callable[[float], float]:
    """% of the map's scale -> its native units (for a header line)."""
    sc = tmap.throttle_scale
    return lambda p: float(sc.from_pct(np.array([p]))[0])
