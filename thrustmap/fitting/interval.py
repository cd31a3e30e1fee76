"""The supported region of a map, and its one prediction interval.

**Supported region.** Where the selected points are in (T, B): the voltages they span (with a
margin of ``VOLTAGE_MARGIN`` of the mean voltage) and, at each voltage B, the thrusts the data
reached there. A motor that reached thrust T at voltage B1 can reach it at any higher voltage
(it needs less throttle), and one that made a low thrust at B1 can make it at any lower voltage,
so the reached range at B is [the lowest thrust of any point, max thrust of points at or below
B], widened by ``THRUST_MARGIN`` of the top thrust (an adaptive run that measured low thrusts
late in a discharge and high ones early still supports 1 N at the start voltage). How far B
lies from the voltages measured near T is the interval's voltage term, not the region's. A map answers inside it from data,
outside it by extrapolation. It replaces the (T, B) bounding box, whose corners may hold no
data at all (a motor fitted on 2S and 3S does not reach its 3S thrust on 2S).

**The interval** (one computation, :meth:`Interval.half_width`, used by fit, predict, the map
file, the report, ``compare``/``evaluate`` coverage and the adaptive bench's stop rule):

    half_width(T, B) = √(q² + (z·σ_p(T, B))² + s² + r² + (κ·ρ(B))²) · (1 + growth · √e(T, B))

``q`` is the 95th percentile of |held-out error| of points inside their training region (by
file when there are several files, so it carries the scatter between files recorded on
different days; else k-fold; never below what the map misses on its own data); ``σ_p`` is the
standard error of the fitted map at (T, B) from the coefficients' covariance (zero for
coefficients held by physics or at a bound), ``z`` its 95 % quantile; ``s`` is what the stand
showed that residuals hide (``systematic_pct``: half the up/down legs' disagreement at equal
thrust, and what a coefficient resting on its bound would change if freed); ``ρ(B)`` is how far
B lies outside the voltages measured, |ln(B / nearest measured voltage)|, and ``κ``
(``VOLTAGE_EXTRAPOLATION_PCT``) the error per unit of it that the motor physics leaves
(calibrated on third-party cross-voltage stand data, see the constant); ``r``
(``recording_pct``, a map fitted on one recording only) what a second recording of the rotor
adds; ``e`` how far T lies outside the thrust the data reached at B, in units of that reach
(T / reach - 1 above it), and ``growth`` (``growth_per_reach``) the extrapolation benchmark's
``EXTRAPOLATION_GROWTH``, or what the map's own folds showed when that is more. Past
``evidence_limit`` (``fitting.extrapolation``) no benchmark shows the interval holds:
:meth:`Interval.standing` says so. A map written before kept ``growth_per_span`` (×(1 + growth
· d), d in thrust spans), which is still read. The interval's ``basis`` says which.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from thrustmap.core.errors import ThrustmapError
from thrustmap.fitting import extrapolation
from thrustmap.fitting.extrapolation import (
    EVIDENCE_LIMIT_THRUST_RATIO,
    EVIDENCE_LIMIT_VOLTAGE_LOG,
    RECORDING_FACTOR,
    RECORDING_WHAT,
)

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

LEVEL = 0.95
Z_LEVEL = 1.959964  # two-sided 95 % normal quantile (the coefficients' error)
MIN_VOLTAGE_UNIT = 0.1  # a voltage distance is measured in at least 10 % of the mean voltage
DEFAULT_GROWTH = 1.0
MIN_GROWTH = 0.5  # extrapolation is never assumed free: at least +50 % per region-size outside
MAX_POINTS = 20_000  # above this, residuals are estimated on an even subsample
KFOLDS = 5
THRUST_MARGIN = 0.03  # of the top thrust reached
VOLTAGE_MARGIN = 0.01  # of the mean voltage
REGION_KNOTS = 24  # voltages at which the reached thrust range is stored
#: κ: % throttle of error per unit of |ln(B / nearest measured voltage)| that a map carried
#: across voltage by motor physics still makes. ``benchmarks/bench_cross_voltage.py
#: --calibrate`` found 12.5 on the Strawson 5-inch motors a1-c8 (24 pairs fitted on 2S, scored
#: on 3S and back: the smallest κ that covers 95 % of their points, pooled); per distance bin
#: that held 87-88 % at |ln(B/B_measured)| 0.2-0.4, so ``benchmarks/bench_extrapolation.py
#: --calibrate`` raised it to the smallest κ holding 90 % in every voltage bin of every tuning
#: rig (Strawson a-c, xNova SR, the simulator). Motors d1-f8 were held out and are scored by
#: both benchmarks.
VOLTAGE_EXTRAPOLATION_PCT = 14.5


@dataclass(frozen=True)
class Region:
    """The supported region: at each knot voltage, the thrust range the data reached there
    (margins included); linear between knots, outside [voltage_lo_v, voltage_hi_v] nothing."""

    voltage_v: tuple[float, ...]
    thrust_lo_n: tuple[float, ...]
    thrust_hi_n: tuple[float, ...]
    voltage_lo_v: float
    voltage_hi_v: float

    @classmethod
    def from_points(cls, thrust_n: FloatArray, voltage_v: FloatArray) -> Region:
        t = np.asarray(thrust_n, float)
        b = np.asarray(voltage_v, float)
        mean_b = float(np.mean(b))
        m_b = VOLTAGE_MARGIN * mean_b
        m_t = THRUST_MARGIN * max(float(np.max(np.abs(t))), 1e-9)
        b_lo, b_hi = float(b.min()) - m_b, float(b.max()) + m_b
        knots = np.linspace(b_lo, b_hi, REGION_KNOTS if b_hi > b_lo else 1)
        hi = np.array([np.max(t[b <= k + m_b], initial=-np.inf) for k in knots])
        # at the low end a knot may see no point: take its neighbour's reach
        hi = np.maximum.accumulate(np.where(np.isfinite(hi), hi, float(t.min())))
        # any thrust made at one voltage can be made at every other below the top reached
        lo = np.full(len(knots), float(t.min()))
        return cls(
            voltage_v=tuple(float(x) for x in knots),
            thrust_lo_n=tuple(float(x) for x in np.maximum(lo - m_t, 0.0)),
            thrust_hi_n=tuple(float(x) for x in hi + m_t),
            voltage_lo_v=b_lo,
            voltage_hi_v=b_hi,
        )

    @classmethod
    def box(cls, t_lo: float, t_hi: float, b_lo: float, b_hi: float) -> Region:
        """A rectangle: the region of a map written before regions were recorded."""
        return cls((b_lo, b_hi), (t_lo, t_lo), (t_hi, t_hi), b_lo, b_hi)

    def thrust_range(self, voltage_v: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        b = np.clip(np.asarray(voltage_v, float), self.voltage_lo_v, self.voltage_hi_v)
        k = np.asarray(self.voltage_v)
        lo = np.interp(b, k, np.asarray(self.thrust_lo_n))
        hi = np.interp(b, k, np.asarray(self.thrust_hi_n))
        return np.asarray(lo, float), np.asarray(hi, float)

    @property
    def thrust_span_n(self) -> float:
        return max(max(self.thrust_hi_n) - min(self.thrust_lo_n), 1e-6)

    @property
    def voltage_unit_v(self) -> float:
        return _voltage_unit(self.voltage_lo_v, self.voltage_hi_v)

    def distance(
        self, thrust_n: npt.ArrayLike, voltage_v: npt.ArrayLike, t_unit: float, b_unit: float
    ) -> FloatArray:
        """Distance outside the region (0 inside), in units of t_unit / b_unit."""
        t, b = np.broadcast_arrays(np.asarray(thrust_n, float), np.asarray(voltage_v, float))
        lo, hi = self.thrust_range(b)
        dt = np.maximum(np.maximum(lo - t, t - hi), 0.0) / t_unit
        db = np.maximum(np.maximum(self.voltage_lo_v - b, b - self.voltage_hi_v), 0.0) / b_unit
        return np.asarray(np.hypot(dt, db), dtype=float)

    def reach_ratio(self, thrust_n: npt.ArrayLike, voltage_v: npt.ArrayLike) -> FloatArray:
        """T / the thrust the data reached at B (margin included): <= 1 within reach. At a
        voltage outside the data, the reach at the nearest measured voltage."""
        t, b = np.broadcast_arrays(np.asarray(thrust_n, float), np.asarray(voltage_v, float))
        _, hi = self.thrust_range(b)
        return np.asarray(t / np.maximum(hi, 1e-9), dtype=float)

    def reach_excess(self, thrust_n: npt.ArrayLike, voltage_v: npt.ArrayLike) -> FloatArray:
        """How far T lies beyond the thrust range at B, in units of the reach there: T / reach
        - 1 above it, (lowest thrust - T) / reach below it, 0 inside."""
        t, b = np.broadcast_arrays(np.asarray(thrust_n, float), np.asarray(voltage_v, float))
        lo, hi = self.thrust_range(b)
        out = np.maximum(np.maximum(t - hi, lo - t), 0.0) / np.maximum(hi, 1e-9)
        return np.asarray(out, dtype=float)

    def thrust_distance(
        self, thrust_n: npt.ArrayLike, voltage_v: npt.ArrayLike, t_unit: float
    ) -> FloatArray:
        """Distance outside the thrust range reached at B (0 inside), in units of t_unit."""
        t, b = np.broadcast_arrays(np.asarray(thrust_n, float), np.asarray(voltage_v, float))
        lo, hi = self.thrust_range(b)
        return np.asarray(np.maximum(np.maximum(lo - t, t - hi), 0.0) / t_unit, dtype=float)

    def voltage_log_distance(self, voltage_v: npt.ArrayLike) -> FloatArray:
        """|ln(B / nearest measured voltage)|: 0 inside the voltages measured."""
        b = np.asarray(voltage_v, float)
        edge = np.clip(b, self.voltage_lo_v, self.voltage_hi_v)
        with np.errstate(divide="ignore", invalid="ignore"):
            rho = np.abs(np.log(np.where(b > 0, b, np.nan) / edge))
        return np.asarray(np.where(np.isfinite(rho), rho, np.inf), dtype=float)

    def contains(self, thrust_n: npt.ArrayLike, voltage_v: npt.ArrayLike) -> BoolArray:
        return np.asarray(self.distance(thrust_n, voltage_v, 1.0, 1.0) <= 0.0)

    def grid(self, n: int = 41) -> tuple[FloatArray, FloatArray]:
        """An n × n grid of (T, B) points covering the region (every point inside it)."""
        b = np.linspace(self.voltage_lo_v, self.voltage_hi_v, n)
        lo, hi = self.thrust_range(b)
        s = np.linspace(0.0, 1.0, n)
        tt = lo[:, None] + (hi - lo)[:, None] * s[None, :]
        return np.asarray(tt, float), np.asarray(np.repeat(b[:, None], n, axis=1), float)

    def describe(self) -> str:
        lo_a, hi_a = self.thrust_range(self.voltage_lo_v)
        lo_b, hi_b = self.thrust_range(self.voltage_hi_v)
        return (
            f"B {self.voltage_lo_v:.2f}..{self.voltage_hi_v:.2f} V; T {float(lo_a):.3f}.."
            f"{float(hi_a):.3f} N at {self.voltage_lo_v:.2f} V, {float(lo_b):.3f}.."
            f"{float(hi_b):.3f} N at {self.voltage_hi_v:.2f} V"
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "meaning": "per voltage, the thrust the selected points reached (with a margin); "
            "linear between knots, nothing outside voltage_lo_v..voltage_hi_v",
            "voltage_v": list(self.voltage_v),
            "thrust_lo_n": list(self.thrust_lo_n),
            "thrust_hi_n": list(self.thrust_hi_n),
            "voltage_lo_v": self.voltage_lo_v,
            "voltage_hi_v": self.voltage_hi_v,
        }


#: thrust knots at which the voltages measured are stored (``VoltageSupport``)
SUPPORT_KNOTS = 12


@dataclass(frozen=True)
class VoltageSupport:
    """At each thrust knot, the voltages the data were measured at near that thrust: a map
    fitted on a 3S pack whose voltage collapsed to 7 V at full throttle was measured at 7 V
    only there, not at 1 N. ``log_distance(T, B)`` is |ln(B / nearest such voltage)|."""

    thrust_n: tuple[float, ...]
    voltage_lo_v: tuple[float, ...]
    voltage_hi_v: tuple[float, ...]

    @classmethod
    def from_points(cls, thrust_n: FloatArray, voltage_v: FloatArray) -> VoltageSupport:
        t = np.asarray(thrust_n, float)
        b = np.asarray(voltage_v, float)
        knots = np.unique(np.quantile(t, np.linspace(0.0, 1.0, SUPPORT_KNOTS)))
        edges = np.r_[-np.inf, 0.5 * (knots[1:] + knots[:-1]), np.inf]
        lo, hi = [], []
        for k in range(len(knots)):
            near = (t >= edges[k]) & (t <= edges[k + 1])
            lo.append(float(b[near].min()) if near.any() else float(b.min()))
            hi.append(float(b[near].max()) if near.any() else float(b.max()))
        return cls(tuple(float(x) for x in knots), tuple(lo), tuple(hi))

    def log_distance(self, thrust_n: npt.ArrayLike, voltage_v: npt.ArrayLike) -> FloatArray:
        t, b = np.broadcast_arrays(np.asarray(thrust_n, float), np.asarray(voltage_v, float))
        k = np.asarray(self.thrust_n)
        lo = np.interp(t, k, np.asarray(self.voltage_lo_v))
        hi = np.interp(t, k, np.asarray(self.voltage_hi_v))
        edge = np.clip(b, lo, hi)
        with np.errstate(divide="ignore", invalid="ignore"):
            rho = np.abs(np.log(np.where(b > 0, b, np.nan) / edge))
        return np.asarray(np.where(np.isfinite(rho), rho, np.inf), dtype=float)

    def to_dict(self) -> dict[str, Any]:
        return {
            "thrust_n": list(self.thrust_n),
            "voltage_lo_v": list(self.voltage_lo_v),
            "voltage_hi_v": list(self.voltage_hi_v),
        }

    @classmethod
    def from_dict(cls, d: Any) -> VoltageSupport | None:
        try:
            t = tuple(float(x) for x in d["thrust_n"])
            lo = tuple(float(x) for x in d["voltage_lo_v"])
            hi = tuple(float(x) for x in d["voltage_hi_v"])
        except (KeyError, TypeError, ValueError):
            return None
        ok = (
            len(t) == len(lo) == len(hi) >= 1
            and all(np.isfinite(t + lo + hi))
            and all(a > 0 and a <= c for a, c in zip(lo, hi, strict=True))
            and all(np.diff(t) > 0)
        )
        return cls(t, lo, hi) if ok else None


@dataclass(frozen=True)
class Standing:
    """Where (T, B) stands: inside the data, extrapolated within the benchmark's evidence, or
    beyond it (``beyond_evidence`` says how far, and where the evidence ends)."""

    inside: bool
    thrust_reach_ratio: float  # T / the thrust the data reached at B (<= 1 within reach)
    voltage_log_distance: float  # |ln(B / voltage measured near T)|, 0 inside
    half_width_pct: float | None  # the map's interval there (growth included; None: none)
    beyond_evidence: str | None  # None: within the limit
    limit_thrust_ratio: float = EVIDENCE_LIMIT_THRUST_RATIO
    limit_voltage_log: float = EVIDENCE_LIMIT_VOLTAGE_LOG

    @property
    def extrapolated(self) -> bool:
        return not self.inside

    def to_dict(self) -> dict[str, Any]:
        return {
            "inside_supported_region": self.inside,
            "extrapolated": self.extrapolated,
            "thrust_reach_ratio": self.thrust_reach_ratio,
            "voltage_log_distance": self.voltage_log_distance,
            "interval_pct": self.half_width_pct,
            "beyond_evidence": self.beyond_evidence is not None,
            "beyond_evidence_reason": self.beyond_evidence,
            "evidence_limit": {
                "thrust_reach_ratio": self.limit_thrust_ratio,
                "voltage_log_distance": self.limit_voltage_log,
            },
        }


def _voltage_unit(lo: float, hi: float) -> float:
    return max(hi - lo, MIN_VOLTAGE_UNIT * 0.5 * (lo + hi), 1e-6)


@dataclass(frozen=True)
class Interval:
    half_width_pct: float  # q: held-out residual quantile inside the training region, % throttle
    growth_per_span: float  # relative widening per region-size of distance outside the region
    thrust_unit_n: float
    voltage_unit_v: float
    region: Region
    basis: str
    level: float = LEVEL
    #: covariance of the raw coefficients (rows × cols), empty: no parameter term
    covariance: tuple[tuple[float, ...], ...] = ()
    z: float = Z_LEVEL
    #: what the stand showed that residuals hide (legs' disagreement, a coefficient on its
    #: bound), % throttle, added in quadrature
    systematic_pct: float = 0.0
    #: κ, % throttle per unit of |ln(B / nearest measured voltage)| (0: a map written before it)
    voltage_pct_per_log: float = 0.0
    #: the voltages measured near each thrust (None: the region's voltage span is used)
    support: VoltageSupport | None = None
    #: relative widening per unit of (T / thrust reached at B - 1) beyond the reach (0: a map
    #: written before it, which widens by growth_per_span per thrust span)
    growth_per_reach: float = 0.0
    #: where the benchmark's evidence ends (T / reach, |ln(B/B_measured)|): predict refuses past
    limit_thrust_ratio: float = EVIDENCE_LIMIT_THRUST_RATIO
    limit_voltage_log: float = EVIDENCE_LIMIT_VOLTAGE_LOG
    #: a map fitted on one recording: what a second recording of the rotor adds (% throttle,
    #: in quadrature; ``RECORDING_FACTOR``), 0 for a map fitted on several files
    recording_pct: float = 0.0

    def voltage_log_distance(self, thrust_n: npt.ArrayLike, voltage_v: npt.ArrayLike) -> FloatArray:
        """ρ: |ln(B / nearest voltage measured near T)|."""
        if self.support is not None:
            return self.support.log_distance(thrust_n, voltage_v)
        t, b = np.broadcast_arrays(np.asarray(thrust_n, float), np.asarray(voltage_v, float))
        return self.region.voltage_log_distance(b)

    def distance(self, thrust_n: npt.ArrayLike, voltage_v: npt.ArrayLike) -> FloatArray:
        return self.region.distance(thrust_n, voltage_v, self.thrust_unit_n, self.voltage_unit_v)

    def parameter_sigma(self, design: FloatArray | None) -> FloatArray | float:
        """Standard error of the fitted map at the design rows (0 without a covariance)."""
        if design is None or not self.covariance:
            return 0.0
        cov = np.asarray(self.covariance, float)
        x = np.asarray(design, float)
        var = np.einsum("ij,jk,ik->i", x, cov, x)
        return np.asarray(np.sqrt(np.clip(var, 0.0, None)), dtype=float)

    def parts(
        self,
        thrust_n: npt.ArrayLike,
        voltage_v: npt.ArrayLike,
        design: FloatArray | None = None,
        *,
        within_recording: bool = False,
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(half-width at the data's distance 0, widening factor, distance outside the region),
        each shaped like the broadcast query. ``design``: the model's rows at the query, flat.
        ``within_recording``: without the second-recording term (what more points of the same
        run can narrow: the adaptive bench's stop rule)."""
        t, b = np.broadcast_arrays(np.asarray(thrust_n, float), np.asarray(voltage_v, float))
        sig = np.reshape(np.broadcast_to(self.parameter_sigma(design), t.size), t.shape)
        rho = self.voltage_log_distance(t, b)
        volt = self.voltage_pct_per_log * rho if self.voltage_pct_per_log else 0.0 * rho
        rec = 0.0 if within_recording else self.recording_pct
        base = np.sqrt(
            self.half_width_pct**2 + (self.z * sig) ** 2 + self.systematic_pct**2 + rec**2 + volt**2
        )
        d = self.distance(t, b)
        if self.growth_per_reach:
            factor = 1.0 + self.growth_per_reach * np.sqrt(self.region.reach_excess(t, b))
        elif self.voltage_pct_per_log:
            # voltage extrapolation is κ's; the growth factor widens for thrust outside only
            factor = 1.0 + self.growth_per_span * self.region.thrust_distance(
                t, b, self.thrust_unit_n
            )
        else:
            factor = 1.0 + self.growth_per_span * d
        return np.asarray(base, float), np.asarray(factor, float), np.asarray(d, float)

    def standing(
        self, thrust_n: float, voltage_v: float, design: FloatArray | None = None
    ) -> Standing:
        """Where (T, B) stands against the data and the benchmark's evidence, with the
        interval there."""
        base, factor, d = (float(x) for x in self.parts(thrust_n, voltage_v, design))
        ratio = float(self.region.reach_ratio(thrust_n, voltage_v))
        rho = float(self.voltage_log_distance(thrust_n, voltage_v))
        beyond = []
        if ratio > self.limit_thrust_ratio:
            beyond.append(
                f"thrust {ratio:.2f}x the reach at {voltage_v:.2f} V (the evidence ends at "
                f"{self.limit_thrust_ratio:.2f}x)"
            )
        if rho > self.limit_voltage_log:
            beyond.append(
                f"{voltage_v:.2f} V is {100 * math.expm1(rho):.0f} % from the voltages measured "
                f"near that thrust, |ln(B/B_measured)| {rho:.2f} (the evidence ends at "
                f"{self.limit_voltage_log:.2f}, {100 * math.expm1(self.limit_voltage_log):.0f} %)"
            )
        return Standing(
            inside=d <= 0.0,
            thrust_reach_ratio=ratio,
            voltage_log_distance=rho,
            half_width_pct=base * factor,
            beyond_evidence="; ".join(beyond) or None,
            limit_thrust_ratio=self.limit_thrust_ratio,
            limit_voltage_log=self.limit_voltage_log,
        )

    def half_width(
        self,
        thrust_n: npt.ArrayLike,
        voltage_v: npt.ArrayLike,
        design: FloatArray | None = None,
        *,
        within_recording: bool = False,
    ) -> FloatArray:
        base, factor, _ = self.parts(thrust_n, voltage_v, design, within_recording=within_recording)
        return np.asarray(base * factor, dtype=float)

    def to_dict(self) -> dict[str, Any]:
        return {
            "level": self.level,
            "half_width_pct": self.half_width_pct,
            "growth_per_span": self.growth_per_span,
            "thrust_unit_n": self.thrust_unit_n,
            "voltage_unit_v": self.voltage_unit_v,
            "z": self.z,
            "parameter_covariance": [list(r) for r in self.covariance],
            "systematic_pct": self.systematic_pct,
            **({"recording_pct": self.recording_pct} if self.recording_pct else {}),
            "voltage_pct_per_log": self.voltage_pct_per_log,
            **({"voltage_support": self.support.to_dict()} if self.support else {}),
            **(
                {
                    "growth_per_reach": self.growth_per_reach,
                    "evidence_limit": {
                        "thrust_reach_ratio": self.limit_thrust_ratio,
                        "voltage_log_distance": self.limit_voltage_log,
                        "meaning": "past these distances outside the supported region no "
                        "benchmark shows the interval holds: predict refuses without "
                        "--extrapolate (T / thrust reached at B; |ln(B / B_measured)|)",
                    },
                }
                if self.growth_per_reach
                else {}
            ),
            "formula": "half_width = sqrt(half_width_pct^2 + (z * sqrt(x' C x))^2 + "
            "systematic_pct^2 + recording_pct^2 + (voltage_pct_per_log * |ln(B / B_edge)|)^2) * "
            "(1 + growth_per_reach * e); x = the model's terms at (T, B), C = "
            "parameter_covariance, B_edge = B clipped to the voltages measured near T "
            "(voltage_support, interpolated in thrust), e = how far T lies outside the "
            "supported region's thrust range at B in units of the thrust reached there "
            "(T / reach - 1 above it); growth_per_span: the same per thrust_unit_n, what this "
            "map's own folds showed, used by readers without growth_per_reach",
            "basis": self.basis,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any], region: Region) -> Interval:
        cov = d.get("parameter_covariance") or []
        raw_lim = d.get("evidence_limit")
        lim: dict[str, Any] = raw_lim if isinstance(raw_lim, dict) else {}
        return cls(
            half_width_pct=float(d["half_width_pct"]),
            growth_per_span=float(d["growth_per_span"]),
            thrust_unit_n=float(d.get("thrust_unit_n") or 0.0) or region.thrust_span_n,
            voltage_unit_v=float(d.get("voltage_unit_v") or 0.0) or region.voltage_unit_v,
            region=region,
            basis=str(d.get("basis", "")),
            level=float(d.get("level", LEVEL)),
            covariance=tuple(tuple(float(x) for x in row) for row in cov),
            z=float(d.get("z", Z_LEVEL)),
            systematic_pct=float(d.get("systematic_pct") or 0.0),
            recording_pct=float(d.get("recording_pct") or 0.0),
            voltage_pct_per_log=float(d.get("voltage_pct_per_log") or 0.0),
            support=VoltageSupport.from_dict(d["voltage_support"])
            if isinstance(d.get("voltage_support"), dict)
            else None,
            growth_per_reach=float(d.get("growth_per_reach") or 0.0),
            limit_thrust_ratio=float(lim.get("thrust_reach_ratio", EVIDENCE_LIMIT_THRUST_RATIO)),
            limit_voltage_log=float(lim.get("voltage_log_distance", EVIDENCE_LIMIT_VOLTAGE_LOG)),
        )


#: fit(t, b, th, file of each point) -> predictor(t, b)
Fitter = Callable[
    [FloatArray, FloatArray, FloatArray, npt.NDArray[np.int64]],
    Callable[[FloatArray, FloatArray], FloatArray],
]


@dataclass(frozen=True)
class IntervalTerms:
    """What ``learn_interval`` adds to the held-out residuals: ``region`` (default: the
    points'), the raw coefficients' ``covariance`` (the parameter term), ``file_fit(f)`` the
    predictor fitted without file f (by-file folds of a map identified from more than the
    points), ``systematic`` (% throttle, what) terms the stand showed beyond the residuals,
    and κ (``voltage_pct_per_log``)."""

    region: Region | None = None
    covariance: FloatArray | None = None
    file_fit: Callable[[int], Callable[[FloatArray, FloatArray], FloatArray]] | None = None
    systematic: Sequence[tuple[float, str]] = ()
    voltage_pct_per_log: float = VOLTAGE_EXTRAPOLATION_PCT


@dataclass
class _HeldOut:
    """Every fold's held-out points: |error|, thrust distance (spans), reach excess, ρ."""

    how: str
    resid: list[FloatArray]
    dist: list[FloatArray]
    excess: list[FloatArray]
    rhos: list[FloatArray]


def _folds(
    fi: npt.NDArray[np.int64], n: int
) -> tuple[list[BoolArray], list[int | None], str] | None:
    """The test masks, the file each holds out (None: k-fold), and how (None: too few)."""
    files = np.unique(fi)
    if len(files) >= 2:
        return [fi == f for f in files], [int(f) for f in files], "by-file"
    k = min(KFOLDS, n // 2)
    if k < 2:
        return None
    fold = np.random.default_rng(0).permutation(n) % k
    return [fold == i for i in range(k)], [None] * k, f"{k}-fold"


def _held_out(
    t: FloatArray, b: FloatArray, th: FloatArray, fi: npt.NDArray[np.int64], fit: Fitter,
    terms: IntervalTerms,
) -> _HeldOut | None:  # fmt: skip
    folds = _folds(fi, len(t))
    if folds is None:
        return None
    splits, fold_files, how = folds
    out = _HeldOut(how, [], [], [], [])
    for test, held in zip(splits, fold_files, strict=True):
        train = ~test
        if train.sum() < 4 or test.sum() == 0:
            continue
        try:
            if terms.file_fit is not None and held is not None:
                predict = terms.file_fit(held)
            else:
                predict = fit(t[train], b[train], th[train], fi[train])
        except (ThrustmapError, np.linalg.LinAlgError, ValueError):
            continue  # a fold the model cannot be fitted on contributes nothing
        out.resid.append(np.abs(predict(t[test], b[test]) - th[test]))
        fold_region = Region.from_points(t[train], b[train])
        # the thrust distance only: voltage extrapolation is κ's (calibrated apart)
        out.dist.append(fold_region.thrust_distance(t[test], b[test], fold_region.thrust_span_n))
        out.excess.append(fold_region.reach_excess(t[test], b[test]))
        out.rhos.append(
            VoltageSupport.from_points(t[train], b[train]).log_distance(t[test], b[test])
        )
    return out if out.resid else None


def learn_interval(
    thrust_n: FloatArray,
    voltage_v: FloatArray,
    throttle_pct: FloatArray,
    file_index: npt.NDArray[np.int64],
    fit: Fitter,
    in_sample_abs_err: FloatArray,
    terms: IntervalTerms | None = None,
) -> Interval | None:
    """Learn the interval from held-out residuals. ``fit(t, b, th, files)`` returns a
    predictor; ``terms``: what is added to them (:class:`IntervalTerms`). None when the data is
    too small to hold anything out."""
    terms = terms or IntervalTerms()
    kappa = terms.voltage_pct_per_log
    n = len(thrust_n)
    region = terms.region or Region.from_points(thrust_n, voltage_v)
    idx = np.arange(n)
    note = ""
    if n > MAX_POINTS:
        idx = idx[:: int(np.ceil(n / MAX_POINTS))]
        note = f", estimated on every {int(np.ceil(n / MAX_POINTS))}th point"
    held = _held_out(thrust_n[idx], voltage_v[idx], throttle_pct[idx], file_index[idx], fit, terms)
    if held is None:
        return None
    # a held-out point outside its fold's voltages carries κ's share of error: the rest of it
    # (in quadrature) is what q and the thrust growth must hold
    rho = np.concatenate(held.rhos)
    r = np.sqrt(np.maximum(np.concatenate(held.resid) ** 2 - (kappa * rho) ** 2, 0.0))
    d = np.concatenate(held.dist)
    inside = d == 0
    q = float(np.percentile(r[inside] if inside.any() else r, 100 * LEVEL))
    # never narrower than what the map misses on its own data
    if len(in_sample_abs_err):
        q = max(q, float(np.percentile(in_sample_abs_err, 100 * LEVEL)))
    q = max(q, 1e-3)
    growth, growth_reach, g_note = _growth(r / q, d, np.concatenate(held.excess), ~inside)
    cov: tuple[tuple[float, ...], ...] = ()
    p_note = "; no parameter term"
    if terms.covariance is not None and np.all(np.isfinite(terms.covariance)):
        cov = tuple(tuple(float(x) for x in row) for row in np.asarray(terms.covariance, float))
        p_note = "; combined with the coefficients' uncertainty at each point"
    kept = [(float(v), w) for v, w in terms.systematic if v > 0 and np.isfinite(v)]
    sys_pct = float(np.sqrt(sum(v * v for v, _ in kept)))
    s_note = "; with " + ", ".join(f"±{v:.2f} % {w}" for v, w in kept) if kept else ""
    rec_pct = 0.0
    if held.how != "by-file":
        # one recording's scatter understates a second recording's (bench_extrapolation.py)
        rec_pct = q * math.sqrt(RECORDING_FACTOR**2 - 1.0)
        s_note += (
            "; one file: the scatter between files recorded on different days is not measured: "
            f"±{rec_pct:.2f} % for {RECORDING_WHAT} (×{RECORDING_FACTOR:g} on the held-out "
            "scatter, benchmarks/bench_extrapolation.py)"
        )
    v_note = (
        f"; away from the voltages measured at that thrust, ±{kappa:g} % per "
        "unit of |ln(B/B_edge)| (calibrated on third-party cross-voltage stand data)"
        if kappa
        else ""
    )
    basis = (
        f"{held.how} held-out residuals, {int(inside.sum())} inside and {int((~inside).sum())} "
        f"outside the training region{note}; {g_note}{p_note}{s_note}{v_note}"
    )
    return Interval(
        q,
        growth,
        region.thrust_span_n,
        region.voltage_unit_v,
        region,
        basis,
        LEVEL,
        cov,
        Z_LEVEL,
        sys_pct,
        kappa,
        VoltageSupport.from_points(thrust_n, voltage_v),
        growth_reach,
        recording_pct=rec_pct,
    )


def _growth(
    rel: FloatArray, d_span: FloatArray, d_reach: FloatArray, out: BoolArray
) -> tuple[float, float, str]:
    """(growth per thrust span as main had it, growth per reach, the basis's words): the
    median relative excess error per unit distance of the held-out points outside their fold's
    region; per reach never below the benchmark's ``EXTRAPOLATION_GROWTH``."""
    excess = np.maximum(rel - 1.0, 0.0)
    if out.sum() >= 3:
        per_span = max(float(np.median(excess[out] / d_span[out])), MIN_GROWTH)
        ok = out & (d_reach > 0)
        own = float(np.median(excess[ok] / np.sqrt(d_reach[ok]))) if ok.sum() >= 3 else 0.0
        where = f"{int(out.sum())} held-out points outside their training region showed {own:.2f}"
    else:
        per_span, own = DEFAULT_GROWTH, 0.0
        where = "no held-out point lay outside its training region"
    # read from its module at each call: the extrapolation benchmark lowers it there to see a
    # map's own growth
    floor = extrapolation.EXTRAPOLATION_GROWTH
    per_reach = max(own, floor)
    note = (
        f"beyond the thrust reached, ×(1 + {per_reach:.2f}·√(T/reach - 1)) ({where}; "
        f"benchmarks/bench_extrapolation.py: {floor:g} holds 90 % of other "
        f"rigs' points up to {EVIDENCE_LIMIT_THRUST_RATIO:g}x the reach)"
    )
    return per_span, per_reach, note


def interval_range(
    interval: Interval,
    design: Callable[[FloatArray, FloatArray], FloatArray],
    *,
    within_recording: bool = False,
) -> tuple[float, float]:
    """The interval's smallest and largest half-width over its supported region (a grid)."""
    tt, bb = interval.region.grid()
    half = interval.half_width(
        tt, bb, design(tt.ravel(), bb.ravel()), within_recording=within_recording
    )
    return float(np.min(half)), float(np.max(half))
