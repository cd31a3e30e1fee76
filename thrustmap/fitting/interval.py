"""Prediction intervals learned from held-out residuals, widening with distance from the data.

A map fitted by ``fit_map`` is re-fitted with part of its data held out (by file when there are
several files, else k-fold) and the held-out errors are collected with how far each held-out
point lay from the training points' box. The interval at a query (T, B) is

    half_width(T, B) = q_inside · (1 + growth · d(T, B))

where ``q_inside`` is the 95th percentile of |held-out error| inside the training box, ``d`` is
the distance outside the map's validity box in units of the box's size (thrust span; voltage
span, but at least ``MIN_VOLTAGE_UNIT`` of the mean voltage) and ``growth`` is the median
relative excess error of held-out points that lay outside their training box per unit distance.
When no held-out point lay outside, ``growth`` is 1 (the interval doubles one box-size out), and
it is never below ``MIN_GROWTH``: assumptions, and the interval's ``basis`` says when they apply.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from thrustmap.core.errors import ThrustmapError

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

LEVEL = 0.95
MIN_VOLTAGE_UNIT = 0.1  # a voltage distance is measured in at least 10 % of the mean voltage
DEFAULT_GROWTH = 1.0
MIN_GROWTH = 0.5  # extrapolation is never assumed free: at least +50 % per box-size outside
MAX_POINTS = 20_000  # above this, residuals are estimated on an even subsample
KFOLDS = 5


@dataclass(frozen=True)
class Interval:
    half_width_pct: float  # at the data (inside the box), % throttle
    growth_per_span: float  # relative widening per box-size of distance outside the box
    thrust_unit_n: float
    voltage_unit_v: float
    thrust_box: tuple[float, float]
    voltage_box: tuple[float, float]
    basis: str
    level: float = LEVEL

    def distance(self, thrust_n: npt.ArrayLike, voltage_v: npt.ArrayLike) -> FloatArray:
        return _distance(
            np.asarray(thrust_n, float),
            np.asarray(voltage_v, float),
            self.thrust_box,
            self.voltage_box,
            self.thrust_unit_n,
            self.voltage_unit_v,
        )

    def half_width(self, thrust_n: npt.ArrayLike, voltage_v: npt.ArrayLike) -> FloatArray:
        d = self.distance(thrust_n, voltage_v)
        return np.asarray(self.half_width_pct * (1.0 + self.growth_per_span * d), dtype=float)

    def to_dict(self) -> dict[str, Any]:
        return {
            "level": self.level,
            "half_width_pct": self.half_width_pct,
            "growth_per_span": self.growth_per_span,
            "thrust_unit_n": self.thrust_unit_n,
            "voltage_unit_v": self.voltage_unit_v,
            "formula": "half_width = half_width_pct * (1 + growth_per_span * d), d = distance "
            "outside the validity box in units of thrust_unit_n / voltage_unit_v",
            "basis": self.basis,
        }

    @classmethod
    def from_dict(
        cls, d: dict[str, Any], thrust_box: tuple[float, float], voltage_box: tuple[float, float]
    ) -> Interval:
        return cls(
            half_width_pct=float(d["half_width_pct"]),
            growth_per_span=float(d["growth_per_span"]),
            thrust_unit_n=float(d.get("thrust_unit_n") or 0.0)
            or max(thrust_box[1] - thrust_box[0], 1e-6),
            voltage_unit_v=float(d.get("voltage_unit_v") or 0.0)
            or _voltage_unit(voltage_box[0], voltage_box[1]),
            thrust_box=thrust_box,
            voltage_box=voltage_box,
            basis=str(d.get("basis", "")),
            level=float(d.get("level", LEVEL)),
        )


def _voltage_unit(lo: float, hi: float) -> float:
    return max(hi - lo, MIN_VOLTAGE_UNIT * 0.5 * (lo + hi), 1e-6)


def _distance(
    t: FloatArray,
    b: FloatArray,
    t_box: tuple[float, float],
    b_box: tuple[float, float],
    t_unit: float,
    b_unit: float,
) -> FloatArray:
    dt = np.maximum(np.maximum(t_box[0] - t, t - t_box[1]), 0.0) / t_unit
    db = np.maximum(np.maximum(b_box[0] - b, b - b_box[1]), 0.0) / b_unit
    return np.asarray(np.maximum(dt, db), dtype=float)


Fitter = Callable[
    [FloatArray, FloatArray, FloatArray], Callable[[FloatArray, FloatArray], FloatArray]
]


def learn_interval(
    thrust_n: FloatArray,
    voltage_v: FloatArray,
    throttle_pct: FloatArray,
    file_index: npt.NDArray[np.int64],
    fit: Fitter,
    in_sample_abs_err: FloatArray,
) -> Interval | None:
    """Learn the interval from held-out residuals. ``fit(t, b, th)`` returns a predictor.
    None when the data is too small to hold anything out."""
    n = len(thrust_n)
    t_box = (float(thrust_n.min()), float(thrust_n.max()))
    b_box = (float(voltage_v.min()), float(voltage_v.max()))
    t_unit = max(t_box[1] - t_box[0], 1e-6)
    b_unit = _voltage_unit(*b_box)
    idx = np.arange(n)
    note = ""
    if n > MAX_POINTS:
        idx = idx[:: int(np.ceil(n / MAX_POINTS))]
        note = f", estimated on every {int(np.ceil(n / MAX_POINTS))}th point"
    t, b, th, fi = thrust_n[idx], voltage_v[idx], throttle_pct[idx], file_index[idx]
    files = np.unique(fi)
    if len(files) >= 2:
        splits = [fi == f for f in files]
        how = "by-file"
    else:
        k = min(KFOLDS, len(t) // 2)
        if k < 2:
            return None
        fold = np.random.default_rng(0).permutation(len(t)) % k
        splits = [fold == i for i in range(k)]
        how = f"{k}-fold"
    resid: list[FloatArray] = []
    dist: list[FloatArray] = []
    for test in splits:
        train = ~test
        if train.sum() < 4 or test.sum() == 0:
            continue
        try:
            predict = fit(t[train], b[train], th[train])
        except (ThrustmapError, np.linalg.LinAlgError, ValueError):
            continue  # a fold the model cannot be fitted on contributes nothing
        resid.append(np.abs(predict(t[test], b[test]) - th[test]))
        tb = (float(t[train].min()), float(t[train].max()))
        bb = (float(b[train].min()), float(b[train].max()))
        dist.append(
            _distance(t[test], b[test], tb, bb, max(tb[1] - tb[0], 1e-6), _voltage_unit(*bb))
        )
    if not resid:
        return None
    r = np.concatenate(resid)
    d = np.concatenate(dist)
    inside = d == 0
    q_base = r[inside] if inside.any() else r
    q = float(np.percentile(q_base, 100 * LEVEL))
    # never narrower than what the map misses on its own data
    q = max(
        q, float(np.percentile(in_sample_abs_err, 100 * LEVEL)) if len(in_sample_abs_err) else q
    )
    q = max(q, 1e-3)
    out = ~inside
    if out.sum() >= 3:
        growth = float(np.median(np.maximum(r[out] / q - 1.0, 0.0) / d[out]))
        g_note = f"growth from {int(out.sum())} held-out points outside their training box"
        if growth < MIN_GROWTH:
            growth = MIN_GROWTH
            g_note += f" (raised to the assumed minimum {MIN_GROWTH:g})"
    else:
        growth = DEFAULT_GROWTH
        g_note = "growth assumed (no held-out point lay outside its training box)"
    basis = (
        f"{how} held-out residuals, {int(inside.sum())} inside and {int(out.sum())} outside "
        f"the training box{note}; {g_note}"
    )
    return Interval(q, growth, t_unit, b_unit, t_box, b_box, basis)


def advice(
    interval: Interval | None,
    thrust_n: FloatArray,
    voltage_v: FloatArray,
    physics_voltage: bool,
    few_points: bool = False,
) -> tuple[str, str]:
    """Two lines for ``fit``: where the map can be trusted, and where data would help most."""
    t_lo, t_hi = float(thrust_n.min()), float(thrust_n.max())
    b_lo, b_hi = float(voltage_v.min()), float(voltage_v.max())
    if interval is None:
        trust = (
            f"trustworthy only at the data (T {t_lo:.3f}..{t_hi:.3f} N, B {b_lo:.2f}..{b_hi:.2f} V);"
            " too few points to learn a prediction interval"
        )
    else:
        q, g = interval.half_width_pct, interval.growth_per_span
        # distance at which the interval has doubled
        reach = 1.0 / g if g > 0 else float("inf")
        if np.isfinite(reach):
            ext_t = reach * interval.thrust_unit_n
            ext_b = reach * interval.voltage_unit_v
            doubled = (
                f"; it doubles by T {max(t_lo - ext_t, 0):.3f}..{t_hi + ext_t:.3f} N, "
                f"B {max(b_lo - ext_b, 0):.2f}..{b_hi + ext_b:.2f} V"
            )
        else:
            doubled = ""
        trust = (
            f"trustworthy to ±{q:.2f} % ({100 * interval.level:.0f} % interval) for "
            f"T {t_lo:.3f}..{t_hi:.3f} N, B {b_lo:.2f}..{b_hi:.2f} V{doubled}"
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
                f"more data would help most beyond the box: above T {t_hi:.3f} N or outside "
                f"B {b_lo:.2f}..{b_hi:.2f} V, where the map extrapolates"
            )
    return trust, more
