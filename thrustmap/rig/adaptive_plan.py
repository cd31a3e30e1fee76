"""The feedback side of an adaptive sweep plan (``rig.plans.adaptive``): a short coarse pass,
then each level chosen from the map being fitted, until the map is good enough or a budget is
spent; across voltage it also moves the battery's voltage (a ``Discharge``, or a
``PackChange`` when discharging cannot get there).

The choosing is injected (a ``Chooser``, in practice ``thrustmap.fitting.adaptive``); this
module does no I/O: the runner hands it each settled point (``observe``) and takes the next
segment from ``AdaptiveDriver.segments()``.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from thrustmap.core.errors import ConfigError
from thrustmap.rig.segments import (
    Discharge,
    PackChange,
    RunSegment,
    Segment,
    hold_segment,
)

log = logging.getLogger(__name__)

#: an adaptive plan goes no higher than a level whose thrust or current reached this share of
#: its interlock limit
LIMIT_HEADROOM = 0.8


#: how far past the plan's range a chosen level may be and still count as its end (the
#: chooser's own slack, fitting.adaptive)
RANGE_SLACK_PCT = 0.5


#: a discharge stops this far (a share) above the minimum-voltage limit, and a run ends
#: once a point reads within it (the next, heavier load would trip the limit)
DISCHARGE_MARGIN = 0.10
#: a point within DISCHARGE_MARGIN of the minimum voltage lowers the plan's top this far below it
PACK_LOW_STEP_PCT = 10.0
#: across voltage: the run ends when the worst interval narrowed by less than STALL_REL over
#: the last STALL_POINTS points at one voltage
STALL_POINTS = 25
STALL_REL = 0.02
#: longest discharge without a time budget, s
DISCHARGE_MAX_S = 900.0


@dataclass(frozen=True)
class SettledPoint:
    """What one hold measured, as the runner hands it to an adaptive plan: the means over the
    hold's recorded part (after settling, or its last ``record_s`` for a fixed hold)."""

    throttle_pct: float
    thrust_n: float
    voltage_v: float | None
    current_a: float | None
    samples: int
    settled: bool
    elapsed_s: float  # plan time when the hold ended
    energy_wh: float  # drawn from the battery since the plan started (stand's V × I)
    label: str = ""


class Assessment(Protocol):
    """A chooser's verdict on the points so far (``thrustmap.fitting.adaptive.Verdict``).

    ``next_pct`` None: no level to propose (no usable fit yet, or the target is met).
    ``pi_at(thrust_n, voltage_v)`` is the interval of the same fit there (for the point just
    measured: its interval after)."""

    @property
    def worst_pi_pct(self) -> float | None: ...  # widest 95 % half-width over the envelope
    @property
    def target_met(self) -> bool: ...
    @property
    def next_pct(self) -> float | None: ...
    @property
    def next_reason(self) -> str: ...
    @property
    def next_pi_pct(self) -> float | None: ...  # the interval where the next point is aimed
    @property
    def pi_at(self) -> Callable[[float, float], float | None]: ...
    @property
    def note(self) -> str: ...  # e.g. the voltage span needs another battery or a supply
    @property
    def move_to_v(self) -> float | None: ...  # across voltage: where the battery must go
    @property
    def move_until_v(self) -> float | None: ...  # ... as read under the heaviest load
    @property
    def move_rest_v(self) -> float | None: ...  # ... as a pack reads it at rest


class Chooser(Protocol):
    """Decides the next command from the points so far at the battery voltage now."""

    target_pi_pct: float

    def assess(
        self,
        points: Sequence[SettledPoint],
        voltage_v: float,
        throttle_range_pct: tuple[float, float] | None = None,
    ) -> Assessment: ...

    def to_dict(self) -> dict[str, Any]: ...


class AdaptiveDriver:
    """The feedback side of an adaptive plan: a short coarse pass (the plan's ``segments``),
    then one hold at a time at the throttle the chooser names, until the chooser's target is met
    over the envelope or a budget ends the run.

    The runner calls ``segments()`` (a generator) and ``observe()`` after each hold. The driver
    keeps a record per point (why it was chosen, the interval before and after) and the stopping
    reason (``summary()``), which the runner writes into the Ds log's sidecar."""

    def __init__(
        self,
        chooser: Chooser,
        coarse_pct: Sequence[float],
        *,
        lo_pct: float,
        hi_pct: float,
        dwell_s: float,
        record_s: float,
        settle: bool = True,
        max_minutes: float | None = None,
        max_wh: float | None = None,
        max_points: int = 200,
        voltage_range_v: tuple[float, float] | None = None,
        connect_pack: Callable[[PackChange], bool] | None = None,
        max_pack_changes: int = 2,
        max_discharges: int = 4,
        discharge: bool = True,
    ) -> None:
        """``voltage_range_v``: across voltage (the chooser judges the target over it);
        ``connect_pack(change)``: asks for another pack (``change.message``, ``change.wanted_v``) with the motor stopped and returns
        whether one was connected (None: the run ends where a pack would be needed);
        ``discharge`` False: a lower voltage is asked for as another pack too (quicker when
        one is at hand: a discharge holds a load for minutes)."""
        if not coarse_pct:
            raise ConfigError("an adaptive plan needs at least one coarse level")
        if not 0 <= lo_pct < hi_pct <= 100:
            raise ConfigError(
                f"adaptive range must satisfy 0 <= from < to <= 100, got {lo_pct:g}..{hi_pct:g}"
            )
        for v in coarse_pct:
            if not lo_pct - 1e-9 <= v <= hi_pct + 1e-9:
                raise ConfigError(f"coarse level {v:g} % is outside {lo_pct:g}..{hi_pct:g} %")
        if max_minutes is not None and max_minutes <= 0:
            raise ConfigError(f"--max-minutes must be positive, got {max_minutes:g}")
        if max_wh is not None and max_wh <= 0:
            raise ConfigError(f"--max-wh must be positive, got {max_wh:g}")
        if max_points < len(coarse_pct):
            raise ConfigError(
                f"max_points ({max_points}) is below the coarse pass ({len(coarse_pct)})"
            )
        self.chooser = chooser
        self.coarse_pct = tuple(float(v) for v in coarse_pct)
        self.lo_pct, self.hi_pct = float(lo_pct), float(hi_pct)
        self.dwell_s, self.record_s, self.settle = dwell_s, record_s, settle
        self.max_minutes, self.max_wh, self.max_points = max_minutes, max_wh, max_points
        self.voltage_range_v = voltage_range_v
        self.connect_pack = connect_pack
        self.max_pack_changes, self.max_discharges = max_pack_changes, max_discharges
        self.discharge = discharge
        #: across voltage: each discharge and pack change (what was asked, what happened)
        self.events: list[dict[str, Any]] = []
        self._min_voltage_v: float | None = None  # the interlock's, from the runner's caps
        self._after_change = False  # a pack was just changed: no verdict on the new one yet
        self._pack_low = ""  # why the run ends before the minimum-voltage limit trips
        self.points: list[SettledPoint] = []
        self.records: list[dict[str, Any]] = []
        self.stop_reason = ""
        self.note = ""
        self.worst_pi_pct: float | None = None
        self._pending: dict[str, Any] = {"reason": "coarse pass", "pi_before_pct": None}
        self._assessment: Assessment | None = None
        self._clipped = 0  # chosen levels in a row outside the plan's range
        self._near_limit = ""  # why the coarse pass ended early (a limit was near)

    # -- the plan's shape (dry run, limits) -----------------------------------------------------
    @property
    def max_throttle_pct(self) -> float:
        return self.hi_pct

    def coarse_segments(self) -> tuple[Segment, ...]:
        return tuple(
            hold_segment(v, self.dwell_s, self.settle, self.record_s, "coarse")
            for v in self.coarse_pct
        )

    def budget_text(self) -> str:
        parts = [f"{self.max_minutes:g} min" if self.max_minutes else "no time budget"]
        parts.append(f"{self.max_wh:g} Wh" if self.max_wh else "no energy budget")
        parts.append(f"at most {self.max_points} points")
        return ", ".join(parts)

    # -- the run --------------------------------------------------------------------------------
    def segments(self) -> Iterator[RunSegment]:
        """The coarse pass, then the chooser's levels, each decided after the previous hold."""
        if self.records:
            raise ConfigError(
                "an adaptive plan runs once (it holds its run's points): build a new one"
            )
        for i, seg in enumerate(self.coarse_segments()):
            if self._near_limit:
                log.info("adaptive plan: coarse pass ends early: %s", self._near_limit)
                break
            self._pending = {
                "reason": f"coarse pass {i + 1}/{len(self.coarse_pct)}",
                "pi_before_pct": None,
            }
            yield seg
        while True:
            a = self._assessment
            stop = self._budget_exhausted() or self._pack_low or self._stalled()
            if stop:
                self.stop_reason = stop
            elif a is not None and a.target_met:
                self.stop_reason = (
                    f"target met: 95 % interval <= {self.chooser.target_pi_pct:g} % over the "
                    f"envelope at the voltages seen (worst {a.worst_pi_pct or 0.0:.2f} %)"
                )
            elif self._clipped >= 3:
                self.stop_reason = (
                    f"the envelope needs throttle outside {self.lo_pct:g}..{self.hi_pct:g} % "
                    "(the plan's range): narrow --thrust-range or widen --from/--to"
                )
            move = None if stop or a is None or a.target_met else a.move_to_v
            if move is not None and not self.stop_reason:
                assert a is not None
                moving = self._voltage_move(a)
                if moving is not None:
                    yield moving
                    continue
            if self.stop_reason:
                for extra in (self._near_limit, self.note):
                    if extra:
                        self.stop_reason += f"; {extra}"
                log.info("adaptive plan ends: %s", self.stop_reason)
                return
            if a is not None and a.next_pct is not None:
                level, reason, before = a.next_pct, a.next_reason, a.next_pi_pct
            else:  # no usable fit: fill the widest gap in throttle
                level = self._largest_gap_pct()
                why = "first hold on the new pack" if self._after_change else "no fit"
                reason = f"{why if a is None else a.next_reason}: largest throttle gap"
                self._after_change = False
                before = None
            clipped = min(max(level, self.lo_pct), self.hi_pct)
            # the chooser allows half a percent of slack at the range's ends (they are
            # reachable): a level within it, held at the end, is not the envelope outrunning
            # the range
            self._clipped = self._clipped + 1 if abs(clipped - level) > RANGE_SLACK_PCT else 0
            if self._clipped:
                reason += f" (wanted {level:.1f} %, held at the plan's range)"
            self._pending = {"reason": reason, "pi_before_pct": before}
            level_pct = min(max(round(clipped, 3), self.lo_pct), self.hi_pct)
            yield hold_segment(level_pct, self.dwell_s, self.settle, self.record_s, "probe")

    def _voltage_move(self, a: Assessment) -> Discharge | PackChange | None:
        """Across voltage: discharge toward ``a.move_to_v`` when holding a load can get there
        within the minimum-voltage limit, else ask for another pack; None with
        ``stop_reason`` set when neither is possible."""
        wanted = float(a.move_to_v or 0.0)
        until = float(a.move_until_v if a.move_until_v is not None else wanted)
        rest = float(a.move_rest_v if a.move_rest_v is not None else wanted)
        now = self._voltage_now() or 0.0
        floor = (
            None if self._min_voltage_v is None else self._min_voltage_v * (1 + DISCHARGE_MARGIN)
        )
        discharges = sum(1 for e in self.events if e["event"] == "discharge")
        changes = sum(1 for e in self.events if e["event"] == "pack change")
        where = a.next_reason
        log.info("adaptive plan, across voltage: %s", where)
        if self.discharge and wanted < now and floor is not None and until >= floor:
            if discharges >= self.max_discharges:
                self.stop_reason = (
                    f"across voltage: {discharges} discharges did not reach {wanted:.2f} V"
                )
                return None
            max_s = DISCHARGE_MAX_S
            if self.max_minutes is not None and self.points:
                max_s = min(max_s, max(60 * self.max_minutes - self.points[-1].elapsed_s, 1.0))
            self._pending = {
                "reason": f"{where}: discharge at {self.hi_pct:g} % until {until:.2f} V under load",
                "pi_before_pct": None,
            }
            self.events.append(
                {
                    "event": "discharge",
                    "from_v": _r(now),
                    "until_v": _r(until),
                    "at_pct": self.hi_pct,
                    "after_point": len(self.records),
                }
            )
            return Discharge(min(round(self.hi_pct, 3), self.hi_pct), until, max_s, self.record_s)
        why_not = (
            "above the pack's voltage"
            if wanted >= now
            else "discharging is off (--no-discharge)"
            if not self.discharge
            else "no minimum-voltage limit is known (--cells)"
            if floor is None
            else f"below what a discharge may reach ({floor:.2f} V under load: the minimum cell "
            f"voltage limit + {100 * DISCHARGE_MARGIN:.0f} %)"
        )
        message = (
            f"The map needs data at about {wanted:.2f} V, {why_not}. The motor is stopped. "
            f"Connect a pack that reads about {rest:.2f} V at rest (another charge, fewer "
            "cells or a bench supply; no more cells than the limits were set for)."
        )
        if self.connect_pack is None or changes >= self.max_pack_changes:
            self.stop_reason = (
                f"across voltage: the range needs data at about {wanted:.2f} V ({why_not})"
                + (
                    f" and {changes} pack changes did not get there"
                    if changes
                    else ": rerun on a pack at that voltage"
                )
            )
            return None
        self._pending = {"reason": f"{where}: pack change", "pi_before_pct": None}
        return PackChange(rest, message)

    def pack_changed(self, wanted_v: float, before_v: float | None, after_v: float | None) -> None:
        """The runner's report of a pack change (the voltage at rest before and after)."""
        self.events.append(
            {
                "event": "pack change",
                "wanted_v": _r(wanted_v),
                "before_v": _r(before_v),
                "after_v": _r(after_v),
                "after_point": len(self.records),
            }
        )
        # the verdict was the old pack's: the first hold on the new one fills the widest
        # throttle gap, and the chooser judges from its point on
        self._assessment = None
        self._after_change = True

    def _stalled(self) -> str:
        """Across voltage, after a voltage move: the worst interval has not narrowed by
        ``STALL_REL`` over the last ``STALL_POINTS`` points since the last move: the target
        is out of reach here, and more points on the same levels only weigh the fit toward
        them."""
        if self.voltage_range_v is None or not self.events:
            return ""  # before a voltage move the chooser decides when to go
        since = max((int(e.get("after_point", 0)) for e in self.events), default=0)
        worst = [r["worst_pi_after_pct"] for r in self.records[since:]]
        worst = [w for w in worst if w is not None]
        if len(worst) <= STALL_POINTS:
            return ""
        before, recent = min(worst[:-STALL_POINTS]), min(worst[-STALL_POINTS:])
        if recent < (1 - STALL_REL) * before:
            return ""
        return (
            f"no progress: the worst interval stayed at ±{recent:.2f} % over the last "
            f"{STALL_POINTS} points (target {self.chooser.target_pi_pct:g} %)"
        )

    def _largest_gap_pct(self) -> float:
        levels = sorted({self.lo_pct, self.hi_pct, *(p.throttle_pct for p in self.points)})
        gaps = [(b - a, 0.5 * (a + b)) for a, b in zip(levels, levels[1:], strict=False)]
        return max(gaps)[1] if gaps else 0.5 * (self.lo_pct + self.hi_pct)

    def observe(self, point: SettledPoint, caps: Mapping[str, float] | None = None) -> None:
        """One hold has ended: refit (through the chooser) and record the point. ``caps``: the
        interlocks' thrust and current limits (``max_thrust_n``, ``max_current_a``); a point
        past ``LIMIT_HEADROOM`` of one ends the coarse pass there and lowers the plan's top to
        its level, so the run stays where the limits allow instead of tripping them."""
        min_v = (caps or {}).get("min_voltage_v")
        if min_v is not None and min_v > 0:
            self._min_voltage_v = float(min_v)
        if point.samples > 0 and math.isfinite(point.thrust_n):
            self.points.append(point)
            self._check_headroom(point, caps or {})
        voltage = self._voltage_now()
        a = (
            self.chooser.assess(self.points, voltage, (self.lo_pct, self.hi_pct))
            if voltage is not None and self.points
            else None
        )
        self._assessment = a
        if a is not None:
            self.worst_pi_pct = a.worst_pi_pct
            self.note = a.note or self.note
        after = (
            None
            if a is None or point.voltage_v is None
            else a.pi_at(point.thrust_n, point.voltage_v)
        )
        self.records.append(
            {
                "point": len(self.records) + 1,
                "throttle_pct": round(point.throttle_pct, 4),
                "thrust_n": _r(point.thrust_n),
                "voltage_v": _r(point.voltage_v),
                "current_a": _r(point.current_a),
                "samples": point.samples,
                "settled": point.settled,
                "elapsed_s": round(point.elapsed_s, 3),
                "energy_wh": round(point.energy_wh, 5),
                "reason": self._pending["reason"],
                "pi_before_pct": _r(self._pending["pi_before_pct"]),
                "pi_after_pct": _r(after),
                "worst_pi_after_pct": _r(None if a is None else a.worst_pi_pct),
            }
        )

    def _check_headroom(self, point: SettledPoint, caps: Mapping[str, float]) -> None:
        min_v = caps.get("min_voltage_v")
        volts = point.voltage_v
        if min_v and volts is not None and volts <= min_v * (1 + DISCHARGE_MARGIN):
            # the pack sags toward its limit: the plan's top comes down a step below this
            # level (a heavier load would trip it); with no room left the run ends
            top = round(point.throttle_pct - PACK_LOW_STEP_PCT, 3)
            near = (
                f"the pack read {volts:.2f} V at {point.throttle_pct:.1f} %, within "
                f"{100 * DISCHARGE_MARGIN:.0f} % of the {min_v:g} V minimum-voltage limit"
            )
            if top <= self.lo_pct + RANGE_SLACK_PCT:
                self._pack_low = f"{near}: the run ends before the limit trips"
            elif top < self.hi_pct:
                self.hi_pct = top
                log.info("adaptive plan: %s: the plan's top is now %g %%", near, top)
        for value, key, what, unit in (
            (point.thrust_n, "max_thrust_n", "thrust", "N"),
            (point.current_a, "max_current_a", "current", "A"),
        ):
            cap = caps.get(key)
            if value is None or cap is None or not cap > 0 or value < LIMIT_HEADROOM * cap:
                continue
            if point.throttle_pct < self.hi_pct:
                self.hi_pct = point.throttle_pct
            if not self._near_limit:
                self._near_limit = (
                    f"{what} {value:.3g} {unit} at {point.throttle_pct:.1f} % is "
                    f"{100 * value / cap:.0f} % of the {cap:g} {unit} limit: the plan's top is "
                    f"now {self.hi_pct:g} %"
                )

    def _voltage_now(self) -> float | None:
        for p in reversed(self.points):
            if p.voltage_v is not None and math.isfinite(p.voltage_v):
                return p.voltage_v
        return None

    def _budget_exhausted(self) -> str:
        last = self.points[-1] if self.points else None
        if len(self.records) >= self.max_points:
            return f"budget reached: {self.max_points} points"
        if last is None:
            return ""
        if self.max_minutes is not None and last.elapsed_s >= 60 * self.max_minutes:
            return f"budget reached: {last.elapsed_s / 60:.1f} of {self.max_minutes:g} min"
        if self.max_wh is not None and last.energy_wh >= self.max_wh:
            return f"budget reached: {last.energy_wh:.2f} of {self.max_wh:g} Wh"
        return ""

    # -- what it says ---------------------------------------------------------------------------
    def time_left_s(self) -> float | None:
        """A rough estimate: the interval of a fit shrinks about as 1/sqrt(points), so the points
        still needed are n·((worst/target)² − 1), at the mean time per point so far; capped by
        the time budget."""
        n = len(self.points)
        if n == 0:
            return None
        elapsed = self.points[-1].elapsed_s
        per_point = elapsed / n
        if n < len(self.coarse_pct):
            left = (len(self.coarse_pct) - n + 2) * per_point
        elif self.worst_pi_pct is None:
            left = 2 * per_point
        else:
            ratio = max(self.worst_pi_pct / self.chooser.target_pi_pct, 1.0)
            left = max(n * (ratio**2 - 1.0), 0.0) * per_point
        # the chooser's minimum number of points comes first
        left = max(left, (getattr(self.chooser, "min_points", 0) - n) * per_point)
        left = min(left, (self.max_points - len(self.records)) * per_point)
        if self.max_minutes is not None:
            left = min(left, max(60 * self.max_minutes - elapsed, 0.0))
        return left

    def status_line(self) -> str:
        worst = "–" if self.worst_pi_pct is None else f"±{self.worst_pi_pct:.2f} %"
        left = self.time_left_s()
        eta = "" if left is None else f", ~{left:.0f} s left"
        energy = f", {self.points[-1].energy_wh:.2f} Wh" if self.points else ""
        return (
            f"worst interval {worst} (target {self.chooser.target_pi_pct:g} %), "
            f"{len(self.records)} points{energy}{eta}"
        )

    def summary(self) -> dict[str, Any]:
        return {
            "target_pi_pct": self.chooser.target_pi_pct,
            "worst_pi_pct": _r(self.worst_pi_pct),
            "stop_reason": self.stop_reason,
            "note": self.note,
            "near_limit": self._near_limit,
            **(
                {
                    "voltage_range_v": list(self.voltage_range_v),
                    "voltage_events": self.events,
                }
                if self.voltage_range_v is not None
                else {}
            ),
            "budget": {
                "max_minutes": self.max_minutes,
                "max_wh": self.max_wh,
                "max_points": self.max_points,
            },
            "points": self.records,
        }

    def to_dict(self) -> dict[str, Any]:
        return {
            "coarse_pct": list(self.coarse_pct),
            "range_pct": [self.lo_pct, self.hi_pct],
            "dwell_s": self.dwell_s,
            "record_s": self.record_s,
            "settle": self.settle,
            "max_minutes": self.max_minutes,
            "max_wh": self.max_wh,
            "max_points": self.max_points,
            "voltage_range_v": None if self.voltage_range_v is None else list(self.voltage_range_v),
            "chooser": self.chooser.to_dict(),
        }


def _r(x: float | None, nd: int = 5) -> float | None:
    return None if x is None or not math.isfinite(x) else round(float(x), nd)
