"""Choosing where an adaptive bench run measures next, from the map it is fitting.

After each settled point the points so far are fitted (the default model, as ``thrustmap fit``
would) and the map's 95 % prediction interval is asked over the envelope: thrusts in the
envelope at the voltages seen. The next command is the throttle the map gives for the thrust
whose prediction is least certain **at the battery voltage now** (the voltage cannot be chosen:
it falls as the battery discharges), among those within ``NEAR_WIDEST`` of the widest, the width weighed by
(1 + its distance from the points measured), so a point is not measured again and again where
one already is; where the interval
is equally wide, the thrust farthest from any point measured near this voltage wins, so the
plan fills gaps and revisits the range as the voltage moves. The run is done once the worst interval
over the envelope is within the target.

Everything the map is asked goes through one function, :func:`fit_interval` (fit the points,
return the prediction and its interval at (T, B)), so a change of the interval's definition
changes the choice without touching the rest. The interval is the map's own
(``ThrustMap.interval_pct``, what ``predict`` and ``fit`` report), and the target must hold over
the envelope and over the map's supported region, the range ``fit`` states: a bench that says
"target met" is a bench whose log ``fit`` calls trustworthy to within the target.

Across voltage (``voltage_range_v``, ``sweep adaptive --across-voltage --voltage-range LO:HI``)
the target must hold over the asked voltage range, not the voltages seen; the map's interval
there carries its voltage term (κ·|ln(B / voltage measured near T)|), so a map measured at one
voltage is not done. Once the interval at the voltage now is within the target, the verdict
names the voltage the range is least certain at (``move_to_v``) and the plan moves the
battery there: a discharge segment or a second pack (``thrustmap.rig.plans``).

This module belongs to ``fitting``: it knows nothing of the rig. The plan
(``thrustmap.rig.plans.adaptive``) receives a :class:`MapChooser` from its caller.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from thrustmap.core.errors import ConfigError, ThrustmapError
from thrustmap.core.units import ThrottleScale

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
#: relative voltage span under which the map's voltage scaling is not identified from data
#: (the identification rule of ``fit``: 5 % of the mean voltage)
IDENTIFY_SPAN_REL = 0.05
PERCENT = ThrottleScale("percent", 0.0, 100.0, "%")
#: candidates whose interval is within this share of the widest are weighed by their distance
#: from the points measured (× (1 + gap)): measuring again on a point narrows little
NEAR_WIDEST = 0.9
#: across voltage: candidate voltages over the asked range
VOLTAGE_CANDIDATES = 5
#: across voltage: the battery's voltage moves once the interval at the voltage now is within
#: this share of the target
MOVE_AT_SHARE = 0.8
#: across voltage: points within this share of the thrust span are "near" a thrust
NEAR_THRUST_REL = 0.25


class PointLike(Protocol):
    """What the chooser reads of a measured point (``thrustmap.rig.plans.SettledPoint``)."""

    @property
    def throttle_pct(self) -> float: ...
    @property
    def thrust_n(self) -> float: ...
    @property
    def voltage_v(self) -> float | None: ...
    @property
    def elapsed_s(self) -> float: ...


@dataclass(frozen=True)
class Fitted:
    """A fit of the points so far: throttle and its 95 % half-width, both in % throttle."""

    throttle_pct: Callable[[FloatArray, FloatArray], FloatArray]
    half_width_pct: Callable[[FloatArray, FloatArray], FloatArray]
    #: the widest half-width over the map's supported region: what ``fit`` prints as
    #: "trustworthy to ±lo..hi %" (None: not known)
    worst_over_region_pct: float | None = None


def fit_interval(
    throttle_pct: FloatArray, thrust_n: FloatArray, voltage_v: FloatArray, *, model: str
) -> Fitted:
    """THE adapter to the fitting API: fit a map to settled points (one steady-state point
    each) and return its prediction and prediction interval at (T, B)."""
    from thrustmap.fitting.dataset import STEP_SUMMARY, Dataset
    from thrustmap.fitting.fit.fitmap import fit_map

    n = len(thrust_n)
    ds = Dataset(
        path="adaptive-points",
        format="adaptive",
        throttle_scale=PERCENT,
        throttle_native=np.asarray(throttle_pct, float),
        thrust_n=np.asarray(thrust_n, float),
        voltage_v=np.asarray(voltage_v, float),
        line=np.arange(1, n + 1, dtype=np.int64),
        meta={"layout": STEP_SUMMARY},
    )
    tmap = fit_map([ds], model=model).map

    def half_width(t: FloatArray, b: FloatArray) -> FloatArray:
        # the map's own interval, exactly as predict and fit evaluate it (with the
        # coefficients' term; issue 31: the bench once asked it without, and stopped early)
        half = tmap.interval_pct(t, b, corrected=False)
        if half is None:
            return np.full(np.broadcast(t, b).shape, np.inf)
        return np.asarray(half, dtype=np.float64)

    def throttle(t: FloatArray, b: FloatArray) -> FloatArray:
        return np.asarray(tmap.throttle_pct(t, b, corrected=False), dtype=np.float64)

    over = tmap.interval_over_region()
    return Fitted(throttle, half_width, None if over is None else float(over[1]))


@dataclass(frozen=True)
class Verdict:
    """Satisfies ``thrustmap.rig.plans.Assessment`` (same fields)."""

    worst_pi_pct: float | None
    target_met: bool
    next_pct: float | None
    next_reason: str
    next_pi_pct: float | None
    pi_at: Callable[[float, float], float | None]
    note: str = ""
    #: across voltage: the voltage the range is least certain at, where the battery must go
    #: next (None: measure at the voltage now, or done)
    move_to_v: float | None = None
    #: ... and the voltage the battery shows under the heaviest load measured (the top of
    #: the envelope) once it is there: what a discharge segment holds until
    move_until_v: float | None = None
    #: ... and the voltage a pack must read at rest to give ``move_to_v`` there (what a
    #: pack change asks for)
    move_rest_v: float | None = None


class MapChooser:
    """Picks the next throttle where the fitted map is least certain at the voltage now.

    ``thrust_range_n``: the envelope the target must hold over; None: from the thrust of the
    lowest coarse level to the highest thrust measured (the top of the plan's throttle range,
    which the limits allow). ``min_points``: no verdict of "done" before this many points.
    ``voltage_range_v``: across voltage, the battery voltages LO..HI the target must hold over
    (None: the voltages seen)."""

    def __init__(
        self,
        target_pi_pct: float,
        *,
        thrust_range_n: tuple[float, float] | None = None,
        model: str = "motor",
        min_points: int = 7,
        candidates: int = 41,
        fit: Callable[..., Fitted] = fit_interval,
        voltage_range_v: tuple[float, float] | None = None,
    ) -> None:
        if not (math.isfinite(target_pi_pct) and target_pi_pct > 0):
            raise ConfigError(f"--target-pi must be a positive % throttle, got {target_pi_pct:g}")
        if thrust_range_n is not None:
            lo, hi = thrust_range_n
            if not (math.isfinite(lo) and math.isfinite(hi) and 0 <= lo < hi):
                raise ConfigError(
                    f"--thrust-range must be LO:HI with 0 <= LO < HI N, got {lo:g}:{hi:g}"
                )
        if voltage_range_v is not None:
            v_lo, v_hi = voltage_range_v
            if not (math.isfinite(v_lo) and math.isfinite(v_hi) and 0 < v_lo < v_hi):
                raise ConfigError(
                    f"--voltage-range must be LO:HI with 0 < LO < HI V, got {v_lo:g}:{v_hi:g}"
                )
        self.voltage_range_v = voltage_range_v
        self.target_pi_pct = float(target_pi_pct)
        self.thrust_range_n = thrust_range_n
        self.model = model
        self.min_points = min_points
        self.candidates = candidates
        self._fit = fit
        if fit is fit_interval:
            # the fit's imports (scipy: over a second) load now, before any motor spins, not
            # during the run while a motor holds its level unattended
            import scipy.optimize  # noqa: F401

            import thrustmap.fitting.fit  # noqa: F401

    def to_dict(self) -> dict[str, Any]:
        return {
            "target_pi_pct": self.target_pi_pct,
            "thrust_range_n": None if self.thrust_range_n is None else list(self.thrust_range_n),
            "voltage_range_v": None if self.voltage_range_v is None else list(self.voltage_range_v),
            "model": self.model,
            "min_points": self.min_points,
            "rule": "least certain thrust at the voltage now; ties to the largest gap",
        }

    def envelope(self, t: FloatArray) -> tuple[float, float]:
        if self.thrust_range_n is not None:
            return self.thrust_range_n
        positive = t[t > 0]
        lo = float(positive.min()) if len(positive) else 0.0
        return lo, float(t.max())

    def assess(
        self,
        points: Sequence[PointLike],
        voltage_v: float,
        throttle_range_pct: tuple[float, float] | None = None,
    ) -> Verdict:
        """The verdict at the voltage now. ``throttle_range_pct``: the plan's range; the
        envelope is judged (and measured) only where the map says that range reaches, so a
        thrust the sagging battery can no longer give inside it is not chased."""
        usable = [p for p in points if p.voltage_v is not None and math.isfinite(p.thrust_n)]
        th = np.array([p.throttle_pct for p in usable], float)
        t = np.array([p.thrust_n for p in usable], float)
        b = np.array([p.voltage_v for p in usable], float)
        if len(usable) < 4:
            return _keep_going("too few points to fit yet")
        try:
            fitted = self._fit(th, t, b, model=self.model)
        except (ThrustmapError, np.linalg.LinAlgError, ValueError) as exc:
            log.info("adaptive fit failed with %d points: %s", len(usable), exc)
            return _keep_going(f"no fit yet ({exc})")
        t_lo, t_hi = self.envelope(t)
        grid_t = np.linspace(t_lo, t_hi, self.candidates)
        b_lo, b_hi = float(b.min()), float(b.max())
        el = np.array([p.elapsed_s for p in usable], float)
        cand_b = _voltage_model(t, el, b, grid_t, float(el.max()), voltage_v)
        if self.voltage_range_v is not None:
            # the asked range, not the voltages seen; its top at each thrust less the sag
            # that thrust's load brings (no pack at HI at rest reads HI under full load)
            v_lo, v_hi = self.voltage_range_v
            top = np.maximum(v_hi - (cand_b[0] - cand_b), v_lo)
            share = np.linspace(0.0, 1.0, VOLTAGE_CANDIDATES)[:, None]
            tt = np.broadcast_to(grid_t, (VOLTAGE_CANDIDATES, len(grid_t)))
            bb = v_lo + share * (top - v_lo)[None, :]
        else:
            grid_b = np.unique(np.array([b_lo, 0.5 * (b_lo + b_hi), b_hi, voltage_v]))
            tt, bb = np.meshgrid(grid_t, grid_b)
        hw = fitted.half_width_pct(tt, bb)
        if throttle_range_pct is not None:
            # one hold's worth of slack: the range's ends themselves are reachable
            lo_pct, hi_pct = throttle_range_pct
            th_grid = fitted.throttle_pct(tt, bb)
            inside = (th_grid >= lo_pct - 0.5) & (th_grid <= hi_pct + 0.5)
            if inside.any():
                hw = np.where(inside, hw, -np.inf)
        worst_all = float(np.max(hw))
        if fitted.worst_over_region_pct is not None and math.isfinite(worst_all):
            # the target holds where fit will say it does: over the supported region too
            worst_all = max(worst_all, fitted.worst_over_region_pct)
        worst = worst_all if math.isfinite(worst_all) else None  # None: no interval yet
        mean_b = float(b.mean())
        note = "" if self.voltage_range_v is not None else _voltage_span_note(b_lo, b_hi, mean_b)

        def pi_at(thrust_n: float, volts: float) -> float | None:
            value = float(fitted.half_width_pct(np.array([thrust_n]), np.array([volts]))[0])
            return value if math.isfinite(value) else None

        met = worst is not None and worst <= self.target_pi_pct and len(usable) >= self.min_points
        if met:
            return Verdict(worst, True, None, "target met", None, pi_at, note)
        # the choice: at the voltage now, widest interval; among equal ones, the largest gap
        # the voltage each candidate would be measured at: now, less the sag its load brings
        # (a linear fit of the points' voltage on thrust and time)
        pi_now = fitted.half_width_pct(grid_t, cand_b)
        if throttle_range_pct is not None:
            th_now = fitted.throttle_pct(grid_t, cand_b)
            inside_now = (th_now >= throttle_range_pct[0] - 0.5) & (
                th_now <= throttle_range_pct[1] + 0.5
            )
            if inside_now.any():
                pi_now = np.where(inside_now, pi_now, -np.inf)
        # gap: distance to the nearest point in thrust (envelope units) and voltage (units of
        # the span that identifies the voltage scaling, 5 % of the mean)
        span_t = max(t_hi - t_lo, 1e-9)
        unit_b = IDENTIFY_SPAN_REL * mean_b
        if self.voltage_range_v is not None and worst is not None:
            move = self._move(hw, tt, bb, grid_t, cand_b, pi_now, (t, b), unit_b)
            if move is not None:
                return Verdict(worst, False, None, move[0], None, pi_at, note, *move[1:])
        gap = np.min(
            np.hypot(
                (grid_t[:, None] - t[None, :]) / span_t, (cand_b[:, None] - b[None, :]) / unit_b
            ),
            axis=1,
        )
        near = np.abs(b - voltage_v) <= unit_b
        wide = pi_now >= float(pi_now.max()) * 0.98
        # the widest interval, weighed by how far it is from the points: a point measured
        # again where one already is narrows the coefficients' term little (the map's
        # interval includes it), so the plan does not sit on one end of the range
        finite = np.isfinite(pi_now)
        top = float(pi_now.max()) if finite.any() else math.inf
        close = finite & (pi_now >= NEAR_WIDEST * top)
        score = np.where(close, np.where(finite, pi_now, 0.0) * (1.0 + gap), -np.inf)
        if not finite.any() or bool(wide.all()):
            score = np.where(wide, gap, -1.0)
        k = int(np.argmax(score))
        target_t = float(grid_t[k])
        level = float(fitted.throttle_pct(np.array([target_t]), np.array([cand_b[k]]))[0])
        if not math.isfinite(level):
            return _keep_going("the map gives no throttle for the envelope")
        flat = bool(wide.all())
        why = (
            (
                f"widest interval ±{float(pi_now[k]):.2f} %"
                if worst is not None
                else "no interval yet (too few points to hold any out)"
            )
            + f" at {target_t:.3g} N, {cand_b[k]:.2f} V"
            + (
                f" (equal over the range: largest gap, {gap[k] * 100:.0f} % of the envelope)"
                if flat
                else ""
            )
            + ("" if near.any() else "; no point yet near this voltage")
        )
        before = float(pi_now[k]) if math.isfinite(float(pi_now[k])) else None
        return Verdict(worst, False, level, why, before, pi_at, note)

    def _move(
        self,
        hw: FloatArray,
        tt: FloatArray,
        bb: FloatArray,
        grid_t: FloatArray,
        cand_b: FloatArray,
        pi_now: FloatArray,
        measured: tuple[FloatArray, FloatArray],
        unit_b: float,
    ) -> tuple[str, float, float, float] | None:
        """Across voltage: once the interval at the voltage now is within the target, the
        (thrust, voltage) of the asked range the map is least certain at, when no point near
        that thrust was measured within half the identifying span of that voltage or on both
        sides of it, and the battery does not give it now: (why, the voltage to move to, the
        voltage under the heaviest load measured once there, the voltage at rest that gives
        it)."""
        t, b = measured
        finite_now = pi_now[np.isfinite(pi_now)]
        if finite_now.size and float(finite_now.max()) > MOVE_AT_SHARE * self.target_pi_pct:
            return None  # there is still something to measure here
        if int(np.sum(np.abs(b - b[-1]) <= 0.5 * unit_b)) < self.min_points:
            # a discharge does not come back: the voltage now is measured well first (the
            # map's voltage term, freed by the move, leans on both ends)
            return None
        k = np.unravel_index(int(np.argmax(hw)), hw.shape)
        t_star, b_star, pi_star = float(tt[k]), float(bb[k]), float(hw[k])
        b_here = float(np.interp(t_star, grid_t, cand_b))
        if abs(b_star - b_here) <= 0.5 * unit_b:
            return None
        span_t = max(float(np.ptp(t)), 1e-9)
        near = b[np.abs(t - t_star) <= NEAR_THRUST_REL * span_t]
        if near.size and (
            float(np.min(np.abs(near - b_star))) <= 0.5 * unit_b
            or (float(near.min()) < b_star < float(near.max()))
        ):
            return None  # measured there, or between voltages measured: measure here
        # the sag between that thrust and the heaviest load measured, from the same voltage
        # model as the candidates (flat when it cannot be fitted)
        sag = float(np.interp(t_star, grid_t, cand_b) - np.interp(float(t.max()), grid_t, cand_b))
        until = b_star - max(sag, 0.0)
        rest = b_star + max(float(cand_b[0]) - b_here, 0.0)  # the sag from no load to T*
        why = (
            f"widest interval ±{pi_star:.2f} % at {t_star:.3g} N, {b_star:.2f} V (the battery "
            f"gives {b_here:.2f} V there now): the voltage must move"
        )
        return why, b_star, until, rest


def _voltage_model(
    t: FloatArray, el: FloatArray, b: FloatArray, grid_t: FloatArray, now_s: float, b_now: float
) -> FloatArray:
    """Voltage expected at each candidate thrust now: B ≈ a + c·T + d·time fitted to the points
    (sag under load, discharge), anchored to the voltage now; flat when it cannot be fitted."""
    if len(t) < 4 or float(np.ptp(t)) <= 0:
        return np.full_like(grid_t, b_now)
    design = np.column_stack([np.ones_like(t), t, el])
    coef, *_ = np.linalg.lstsq(design, b, rcond=None)
    if not np.all(np.isfinite(coef)):
        return np.full_like(grid_t, b_now)
    c_t = min(float(coef[1]), 0.0)  # more thrust never raises the battery voltage
    predicted_now = float(coef[0] + coef[2] * now_s)
    return np.asarray(predicted_now + c_t * grid_t, dtype=np.float64)


def _voltage_span_note(b_lo: float, b_hi: float, mean_b: float) -> str:
    """What to say when the points' voltages are too close to identify the voltage scaling."""
    span = b_hi - b_lo
    if span >= IDENTIFY_SPAN_REL * mean_b:
        return ""
    return (
        f"voltage span {span:.2f} V ({100 * span / mean_b:.1f} % of {mean_b:.2f} V): "
        "how the map scales with voltage rests on motor physics; for a measured "
        "scaling, continue on a battery at another charge or a bench supply "
        f"(at least {IDENTIFY_SPAN_REL * mean_b:.1f} V apart)"
    )


def _keep_going(why: str) -> Verdict:
    return Verdict(None, False, None, why, None, lambda t, b: None)
