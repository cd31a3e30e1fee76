"""Sweep plans: descriptions of a throttle timeline. They do no I/O.

A plan is a list of segments in percent of the throttle output's native scale. It can be
printed, timed, and checked against the limits before any motor spins (``--dry-run``); the
runner executes it. The seed paper's four experiments (its Fig. 5) are provided:
``steps`` (up-steps returning to a low level), ``stairs-up``, ``stairs-down`` and ``ramp`` (up
then down), plus ``explicit`` for a user's own list of levels, and ``adaptive``: a short coarse pass, then
each level chosen from the map being fitted (``AdaptiveDriver``; the choosing is injected, see
``thrustmap.fitting.adaptive``), until the map is good enough or a budget is spent. Across
voltage (``across_voltage``) an adaptive plan also moves the battery's voltage where the map
needs it: a ``Discharge`` (hold a load until the voltage has fallen, within the interlocks) or,
when discharging cannot get there, a ``PackChange`` (the runner stops the motor, verifies the
stop, asks for the other pack and checks that the voltage moved).

The segments live in ``rig.segments`` and the adaptive plan's feedback side in
``rig.adaptive_plan``; a script needs only this module (``thrustmap.plans``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, NamedTuple

from thrustmap.core.errors import ConfigError
from thrustmap.rig.adaptive_plan import AdaptiveDriver, Chooser
from thrustmap.rig.segments import (
    Discharge,
    Hold,
    PackChange,
    Ramp,
    RunSegment,
    Segment,
    hold_segment,
)

__all__ = [
    "PLANS",
    "Plan",
    "adaptive",
    "explicit",
    "ramp",
    "stairs",
    "steps",
]


@dataclass(frozen=True)
class Plan:
    name: str
    segments: tuple[Segment, ...]
    params: dict[str, Any] = field(default_factory=dict)
    #: an adaptive plan's feedback side: ``segments`` is then its coarse pass, and the runner
    #: takes the levels that follow from ``adaptive.segments()``
    adaptive: AdaptiveDriver | None = field(default=None, compare=False)
    #: the most the user allowed (``--to``, an explicit plan's highest level): no segment may
    #: lie above it, checked here when the plan is built and again for every level an adaptive
    #: plan chooses as it runs (None: the plan's own highest level)
    ceiling_pct: float | None = None

    def __post_init__(self) -> None:
        if self.ceiling_pct is None:
            return
        for seg in self.segments:
            _within_ceiling(seg, self.ceiling_pct, self.name)
        if self.adaptive is not None and self.adaptive.max_throttle_pct > self.ceiling_pct:
            raise ConfigError(
                f"plan '{self.name}': its range reaches {self.adaptive.max_throttle_pct:g} %, "
                f"above --to {self.ceiling_pct:g} %"
            )

    @property
    def max_throttle_pct(self) -> float:
        return max(
            [
                (s.throttle_pct if isinstance(s, Hold) else max(s.start_pct, s.end_pct))
                for s in self.segments
            ]
            + ([] if self.adaptive is None else [self.adaptive.max_throttle_pct])
        )

    def run_segments(self) -> Iterator[RunSegment]:
        """What the runner executes: the segments, or an adaptive plan's levels as it decides."""
        if self.adaptive is None:
            yield from self.segments
            return
        for seg in self.adaptive.segments():
            if self.ceiling_pct is not None:
                _within_ceiling(seg, self.ceiling_pct, self.name)
            yield seg

    @property
    def duration_s(self) -> float:
        """Longest duration (settling holds may end early)."""
        return sum(s.dwell_s if isinstance(s, Hold) else s.duration_s for s in self.segments)

    def max_ramp_slew_pct_s(self) -> float:
        rates = [
            abs(s.end_pct - s.start_pct) / s.duration_s
            for s in self.segments
            if isinstance(s, Ramp)
        ]
        return max(rates, default=0.0)

    def max_step_pct(self) -> float:
        """Largest instantaneous jump between consecutive segments (the runner slews it)."""
        prev = 0.0
        worst = 0.0
        for s in self.segments:
            start = s.throttle_pct if isinstance(s, Hold) else s.start_pct
            worst = max(worst, abs(start - prev))
            prev = s.throttle_pct if isinstance(s, Hold) else s.end_pct
        return worst

    def timeline(self) -> Iterator[tuple[float, Segment]]:
        """(start time, segment) pairs, assuming every hold lasts its full dwell."""
        t = 0.0
        for s in self.segments:
            yield t, s
            t += s.dwell_s if isinstance(s, Hold) else s.duration_s

    def describe(self, scale_lo: float = 0.0, scale_hi: float = 100.0, unit: str = "%") -> str:
        def native(pct: float) -> str:
            """The level in the FC's own unit, beside the %; nothing when that unit is %."""
            if unit == "%" and (scale_lo, scale_hi) == (0.0, 100.0):
                return ""
            shown = "µs" if unit == "us" else unit
            return f" ({scale_lo + pct / 100 * (scale_hi - scale_lo):.0f} {shown})"

        lines = [
            f"plan '{self.name}': {len(self.segments)} segments, up to {self.duration_s:.1f} s, "
            f"ceiling {self.max_throttle_pct:.1f} %{native(self.max_throttle_pct)}"
        ]
        for t, s in self.timeline():
            if isinstance(s, Hold):
                how = (
                    f"until settled (max {s.dwell_s:.1f} s) + {s.record_s:.1f} s"
                    if s.settle
                    else f"{s.dwell_s:.1f} s"
                )
                lines.append(
                    f"  {t:7.1f} s  {s.label:<6} {s.throttle_pct:5.1f} %{native(s.throttle_pct)}  {how}"
                )
            else:
                lines.append(
                    f"  {t:7.1f} s  {s.label:<6} {s.start_pct:5.1f} -> {s.end_pct:5.1f} % over "
                    f"{s.duration_s:.1f} s ({abs(s.end_pct - s.start_pct) / s.duration_s:.2f} %/s)"
                )
        a = self.adaptive
        if a is not None:
            lines[0] = (
                f"plan 'adaptive': coarse pass of {len(self.segments)} holds (up to "
                f"{self.duration_s:.1f} s), then one hold at a time between {a.lo_pct:g} and "
                f"{a.hi_pct:g} %{native(a.hi_pct)} where the map is least certain"
            )
            lines.append(
                f"  then: target 95 % interval <= {a.chooser.target_pi_pct:g} % throttle over "
                f"the envelope; stops at the target or the budget ({a.budget_text()})"
            )
            if a.voltage_range_v is not None:
                lo_v, hi_v = a.voltage_range_v
                lines.append(
                    f"  across voltage {lo_v:g}..{hi_v:g} V: once the voltage now is measured, "
                    + (
                        f"discharge at {a.hi_pct:g} % down to where the map is least certain, "
                        "or, where discharging cannot reach (the minimum cell voltage, or a "
                        "voltage above the pack's), stop the motor and ask for another pack"
                        if a.discharge
                        else "stop the motor and ask for another pack at the voltage where "
                        "the map is least certain"
                    )
                )
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        out = {
            "name": self.name,
            "params": self.params,
            "segments": [{"type": type(s).__name__.lower(), **asdict(s)} for s in self.segments],
        }
        if self.adaptive is not None:
            out["adaptive"] = self.adaptive.to_dict()
        return out


def _segment_top_pct(seg: RunSegment) -> float:
    """The highest level a segment commands (a pack change commands none)."""
    if isinstance(seg, Ramp):
        return max(seg.start_pct, seg.end_pct)
    if isinstance(seg, (Hold, Discharge)):
        return seg.throttle_pct
    return 0.0


def _within_ceiling(seg: RunSegment, ceiling_pct: float, plan_name: str) -> None:
    """Refuse a segment above what the user allowed (never commanded: the plan is refused)."""
    top = _segment_top_pct(seg)
    if top > ceiling_pct:
        raise ConfigError(
            f"plan '{plan_name}': {seg.label} at {top:g} % is above --to {ceiling_pct:g} %; "
            "nothing is commanded above what was asked"
        )


#: the most a planned sweep may be: a bench run on a battery lasts minutes, one on a supply
#: hours at most; a plan beyond either is a mistyped --step, --dwell, --duration or --repeats
#: (``--step 0.001``: 50,001 levels, 42 h), and it is refused before it is even built
MAX_PLAN_S = 4 * 3600.0
MAX_PLAN_SEGMENTS = 5000


def _check_size(name: str, segments: int, duration_s: float) -> None:
    """Refuse a plan of more than ``MAX_PLAN_SEGMENTS`` segments or ``MAX_PLAN_S``."""
    if segments <= MAX_PLAN_SEGMENTS and duration_s <= MAX_PLAN_S:  # (NaN is refused earlier)
        return
    raise ConfigError(
        f"plan '{name}' would be {segments:,} segments over {duration_s / 3600:,.1f} h; a sweep "
        f"is at most {MAX_PLAN_SEGMENTS:,} segments and {MAX_PLAN_S / 3600:g} h: check --step, "
        "--dwell, --duration and --repeats"
    )


#: explicit levels all at or below this are fractions typed for percent (0.3 for 30 %)
FRACTION_TOP = 1.0


def _finite_pct(value: float, option: str) -> float:
    """A level option in 0..100 % (also refusing NaN and infinity), named when it is not."""
    if not 0.0 <= value <= 100.0:
        raise ConfigError(f"{option} {value:g}: expected a throttle level in 0..100 %")
    return float(value)


def levels_between(start_pct: float, stop_pct: float, step_pct: float) -> list[float]:
    """The levels ``start_pct``, ``start_pct + step_pct``, ... that do not pass ``stop_pct``,
    then ``stop_pct`` itself: a sweep ends exactly at ``--to`` and no level lies above it,
    whatever the step (``10..60`` by 20 is 10, 30, 50, 60; by 100 it is 10, 60)."""
    start = _finite_pct(start_pct, "--from")
    stop = _finite_pct(stop_pct, "--to")
    if not step_pct > 0 or not math.isfinite(step_pct):  # also NaN
        raise ConfigError(f"--step {step_pct:g}: expected a positive increment in %")
    if stop < start:
        raise ConfigError(f"--to ({stop:g} %) must be at least --from ({start:g} %)")
    n = math.floor((stop - start) / step_pct + 1e-9)
    levels = [min(round(start + k * step_pct, 6), stop) for k in range(n + 1)]
    if levels[-1] < stop - 1e-6:
        levels.append(stop)
    else:
        levels[-1] = stop
    return levels


class Low(NamedTuple):
    """The level ``steps`` returns to between steps, and how long it holds it there."""

    pct: float = 10.0
    dwell_s: float = 3.0


#: steps' default low level: 10 % held 3 s
DEFAULT_LOW = Low()


def steps(
    start_pct: float = 15,
    stop_pct: float = 60,
    step_pct: float = 5,
    *,
    low: Low = DEFAULT_LOW,
    dwell_s: float = 3.0,
    settle: bool = False,
    record_s: float = 1.0,
    repeats: int = 1,
) -> Plan:
    """Up-steps from a low level, returning to it between steps (paper: *-steps.csv).

    A level equal to the low level is no step (it would hold the low level twice), so it is left
    out: ``--from 10 --low 10`` steps to 15, 20, ... and back to 10 between them.
    """
    low_pct, low_dwell_s = low
    low_pct = _finite_pct(low_pct, "--low")
    if low_pct > stop_pct:
        raise ConfigError(
            f"--low {low_pct:g} % is above --to {stop_pct:g} %: steps returns to --low between "
            "steps, so it must not exceed --to"
        )
    levels = [
        lv for lv in levels_between(start_pct, stop_pct, step_pct) if abs(lv - low_pct) > 1e-9
    ]
    if not levels:
        raise ConfigError(
            f"--from/--to: every level in {start_pct:g}..{stop_pct:g} % equals --low "
            f"({low_pct:g} %): nothing to step to"
        )
    rounds = max(repeats, 1) * len(levels)
    _check_size("steps", 1 + 2 * rounds, low_dwell_s + rounds * (dwell_s + low_dwell_s))
    segs: list[Segment] = [hold_segment(low_pct, low_dwell_s, settle, record_s, "low")]
    for _ in range(max(repeats, 1)):
        for level in levels:
            segs.append(hold_segment(level, dwell_s, settle, record_s, "step"))
            segs.append(hold_segment(low_pct, low_dwell_s, settle, record_s, "low"))
    return Plan(
        "steps",
        tuple(segs),
        {
            "from": start_pct,
            "to": stop_pct,
            "step": step_pct,
            "low": low_pct,
            "dwell_s": dwell_s,
            "settle": settle,
            "repeats": repeats,
        },
        ceiling_pct=stop_pct,
    )


def stairs(
    start_pct: float = 10,
    stop_pct: float = 60,
    step_pct: float = 5,
    *,
    down: bool = False,
    dwell_s: float = 3.0,
    settle: bool = False,
    record_s: float = 1.0,
    repeats: int = 1,
) -> Plan:
    """Stairs up (paper: *-steps-up.csv) or down through the levels."""
    levels = levels_between(start_pct, stop_pct, step_pct)
    if down:
        levels = levels[::-1]
    count = max(repeats, 1) * len(levels)
    _check_size("stairs-down" if down else "stairs-up", count, count * dwell_s)
    segs = tuple(
        hold_segment(v, dwell_s, settle, record_s, "stair")
        for _ in range(max(repeats, 1))
        for v in levels
    )
    return Plan(
        "stairs-down" if down else "stairs-up",
        segs,
        {"from": start_pct, "to": stop_pct, "step": step_pct, "dwell_s": dwell_s, "settle": settle},
        ceiling_pct=stop_pct,
    )


def ramp(
    start_pct: float = 0,
    stop_pct: float = 80,
    *,
    duration_s: float = 30.0,
    repeats: int = 1,
    hold_s: float = 1.0,
) -> Plan:
    """Slow ramp up then down (paper: *-ramp.csv); pairs of up/down ramps cancel rotor lag."""
    if duration_s <= 0:
        raise ConfigError(f"ramp duration must be positive, got {duration_s:g} s")
    levels_between(start_pct, stop_pct, max(stop_pct - start_pct, 1e-6))
    _check_size("ramp", 4 * max(repeats, 1), max(repeats, 1) * 2 * (duration_s + hold_s))
    segs: list[Segment] = []
    for _ in range(max(repeats, 1)):
        segs.append(hold_segment(start_pct, hold_s, False, 0.0, "base"))
        segs.append(Ramp(start_pct, stop_pct, duration_s, "up"))
        segs.append(hold_segment(stop_pct, hold_s, False, 0.0, "top"))
        segs.append(Ramp(stop_pct, start_pct, duration_s, "down"))
    return Plan(
        "ramp",
        tuple(segs),
        {"from": start_pct, "to": stop_pct, "duration_s": duration_s, "repeats": repeats},
        ceiling_pct=stop_pct,
    )


def explicit(
    levels_pct: Sequence[float],
    *,
    dwell_s: float = 3.0,
    settle: bool = False,
    record_s: float = 1.0,
) -> Plan:
    if not levels_pct:
        raise ConfigError("an explicit plan needs at least one level")
    for v in levels_pct:
        if not 0 <= v <= 100:
            raise ConfigError(f"level {v:g} % is outside 0..100 %")
    top = max(levels_pct)
    if 0 < top <= FRACTION_TOP:
        raise ConfigError(
            f"--levels: every level is {FRACTION_TOP:g} % or less (highest {top:g} %), below any "
            f"ESC's spin-up: fractions? {top:g} is {top * 100:g} %; levels are in percent"
        )
    _check_size("explicit", len(levels_pct), len(levels_pct) * dwell_s)
    return Plan(
        "explicit",
        tuple(hold_segment(v, dwell_s, settle, record_s, "level") for v in levels_pct),
        {"levels": list(levels_pct), "dwell_s": dwell_s, "settle": settle},
        ceiling_pct=max(levels_pct),
    )


@dataclass(frozen=True)
class Budget:
    """What may end an adaptive run before its target: minutes, watt-hours, points."""

    max_minutes: float | None = None
    max_wh: float | None = None
    max_points: int = 200


@dataclass(frozen=True)
class AcrossVoltage:
    """An adaptive run across voltage: the range the map must cover (volts at the battery),
    how another pack is asked for (None: the run ends where one would be needed) and whether
    the bench pack may be discharged toward a lower voltage."""

    voltage_range_v: tuple[float, float]
    connect_pack: Callable[[PackChange], bool] | None = None
    discharge: bool = True


def adaptive(
    chooser: Chooser,
    start_pct: float = 10.0,
    stop_pct: float = 60.0,
    *,
    coarse_levels: int = 5,
    dwell_s: float = 3.0,
    record_s: float = 1.0,
    budget: Budget | None = None,
    across: AcrossVoltage | None = None,
) -> Plan:
    """An adaptive plan: ``coarse_levels`` evenly spaced holds from ``start_pct`` to
    ``stop_pct``, then holds chosen one at a time by ``chooser`` (for the fitted map's least
    certain throttle at the battery voltage now), never outside ``start_pct..stop_pct``, until
    the chooser's target is met or the ``budget`` ends it. Every hold settles (``dwell_s`` is its
    maximum, then ``record_s`` is recorded)."""
    budget = budget or Budget()
    if coarse_levels < 2:
        raise ConfigError(f"--coarse {coarse_levels}: the coarse pass needs at least 2 levels")
    _finite_pct(start_pct, "--from")
    _finite_pct(stop_pct, "--to")
    if stop_pct <= start_pct:
        raise ConfigError(f"--to ({stop_pct:g} %) must be above --from ({start_pct:g} %)")
    step = (stop_pct - start_pct) / (coarse_levels - 1)
    coarse = [
        min(max(round(start_pct + k * step, 3), start_pct), stop_pct) for k in range(coarse_levels)
    ]
    coarse[-1] = stop_pct
    driver = AdaptiveDriver(
        chooser,
        coarse,
        lo_pct=start_pct,
        hi_pct=stop_pct,
        dwell_s=dwell_s,
        record_s=record_s,
        settle=True,
        max_minutes=budget.max_minutes,
        max_wh=budget.max_wh,
        max_points=budget.max_points,
        voltage_range_v=None if across is None else across.voltage_range_v,
        connect_pack=None if across is None else across.connect_pack,
        discharge=True if across is None else across.discharge,
    )
    return Plan(
        "adaptive",
        driver.coarse_segments(),
        {
            "from": start_pct,
            "to": stop_pct,
            "coarse_levels": coarse_levels,
            "dwell_s": dwell_s,
            "settle": True,
            "target_pi_pct": chooser.target_pi_pct,
            "max_minutes": budget.max_minutes,
            "max_wh": budget.max_wh,
            **({"voltage_range_v": list(across.voltage_range_v)} if across else {}),
        },
        adaptive=driver,
        ceiling_pct=stop_pct,
    )


PLANS = ("steps", "stairs-up", "stairs-down", "ramp", "explicit", "adaptive")
