"""Sweep plans: descriptions of a throttle timeline. They do no I/O.

A plan is a list of segments in percent of the throttle output's native scale. It can be
printed, timed, and checked against the limits before any motor spins (``--dry-run``); the
runner executes it. The seed paper's four experiments (its Fig. 5) are provided:
``steps`` (up-steps returning to a low level), ``stairs-up``, ``stairs-down`` and ``ramp`` (up
then down), plus ``explicit`` for a user's own list of levels.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

from thrustmap.core.errors import ConfigError


@dataclass(frozen=True)
class Hold:
    """Hold a throttle level. With ``settle``, hold until thrust settles (at most ``dwell_s``)
    and then record ``record_s`` more; otherwise hold exactly ``dwell_s``."""

    throttle_pct: float
    dwell_s: float
    settle: bool = False
    record_s: float = 1.0
    label: str = "hold"


@dataclass(frozen=True)
class Ramp:
    """Move linearly from ``start_pct`` to ``end_pct`` over ``duration_s``."""

    start_pct: float
    end_pct: float
    duration_s: float
    label: str = "ramp"


Segment = Hold | Ramp


@dataclass(frozen=True)
class Plan:
    name: str
    segments: tuple[Segment, ...]
    params: dict[str, Any] = field(default_factory=dict)

    @property
    def max_throttle_pct(self) -> float:
        return max(
            (s.throttle_pct if isinstance(s, Hold) else max(s.start_pct, s.end_pct))
            for s in self.segments
        )

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
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "params": self.params,
            "segments": [{"type": type(s).__name__.lower(), **asdict(s)} for s in self.segments],
        }


def _levels(start_pct: float, stop_pct: float, step_pct: float) -> list[float]:
    if step_pct <= 0:
        raise ConfigError(f"step must be positive, got {step_pct:g} %")
    if not 0 <= start_pct <= 100 or not 0 <= stop_pct <= 100:
        raise ConfigError(f"levels must lie in 0..100 %, got {start_pct:g}..{stop_pct:g}")
    if stop_pct < start_pct:
        raise ConfigError(f"--to ({stop_pct:g} %) must be at least --from ({start_pct:g} %)")
    n = int(round((stop_pct - start_pct) / step_pct + 1e-9))
    levels = [round(start_pct + k * step_pct, 6) for k in range(n + 1)]
    if levels[-1] < stop_pct - 1e-9:
        levels.append(stop_pct)
    return levels


def _hold(level: float, dwell_s: float, settle: bool, record_s: float, label: str) -> Hold:
    if dwell_s <= 0:
        raise ConfigError(f"dwell must be positive, got {dwell_s:g} s")
    return Hold(level, dwell_s, settle, record_s, label)


def steps(
    start_pct: float = 15,
    stop_pct: float = 60,
    step_pct: float = 5,
    *,
    low_pct: float = 10,
    dwell_s: float = 3.0,
    low_dwell_s: float = 3.0,
    settle: bool = False,
    record_s: float = 1.0,
    repeats: int = 1,
) -> Plan:
    """Up-steps from a low level, returning to it between steps (paper: *-steps.csv).

    A level equal to the low level is no step (it would hold the low level twice), so it is left
    out: ``--from 10 --low 10`` steps to 15, 20, ... and back to 10 between them.
    """
    levels = [lv for lv in _levels(start_pct, stop_pct, step_pct) if abs(lv - low_pct) > 1e-9]
    if not levels:
        raise ConfigError(
            f"steps: every level in {start_pct:g}..{stop_pct:g} % equals the low level "
            f"({low_pct:g} %): nothing to step to"
        )
    segs: list[Segment] = [_hold(low_pct, low_dwell_s, settle, record_s, "low")]
    for _ in range(max(repeats, 1)):
        for level in levels:
            segs.append(_hold(level, dwell_s, settle, record_s, "step"))
            segs.append(_hold(low_pct, low_dwell_s, settle, record_s, "low"))
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
    levels = _levels(start_pct, stop_pct, step_pct)
    if down:
        levels = levels[::-1]
    segs = tuple(
        _hold(v, dwell_s, settle, record_s, "stair") for _ in range(max(repeats, 1)) for v in levels
    )
    return Plan(
        "stairs-down" if down else "stairs-up",
        segs,
        {"from": start_pct, "to": stop_pct, "step": step_pct, "dwell_s": dwell_s, "settle": settle},
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
    _levels(start_pct, stop_pct, max(stop_pct - start_pct, 1e-6))
    segs: list[Segment] = []
    for _ in range(max(repeats, 1)):
        segs.append(_hold(start_pct, hold_s, False, 0.0, "base"))
        segs.append(Ramp(start_pct, stop_pct, duration_s, "up"))
        segs.append(_hold(stop_pct, hold_s, False, 0.0, "top"))
        segs.append(Ramp(stop_pct, start_pct, duration_s, "down"))
    return Plan(
        "ramp",
        tuple(segs),
        {"from": start_pct, "to": stop_pct, "duration_s": duration_s, "repeats": repeats},
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
    return Plan(
        "explicit",
        tuple(_hold(v, dwell_s, settle, record_s, "level") for v in levels_pct),
        {"levels": list(levels_pct), "dwell_s": dwell_s, "settle": settle},
    )


PLANS = ("steps", "stairs-up", "stairs-down", "ramp", "explicit")
