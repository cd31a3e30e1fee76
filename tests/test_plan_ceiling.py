"""No plan commands a level above what the user asked (issue 44 item 1).

A property test over every plan type: for random ``--from/--to/--step/--dwell`` (and, for an
adaptive plan, a chooser proposing random levels, in range or far outside it), every level the
plan would command lies at or below ``--to``; a plan that cannot honour the request is refused
with a ``ConfigError`` naming the option. Also the CLI rows seen on 19a0a12 (stairs 10/30/50/70
for ``--to 60 --step 20``; ``--step 100`` refused as "reaches 110 %").
"""

from __future__ import annotations

import math
import random
import subprocess
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from thrustmap.core.errors import ConfigError
from thrustmap.rig import plans
from thrustmap.rig.adaptive_plan import SettledPoint
from thrustmap.rig.segments import Discharge, Hold, PackChange, Ramp, RunSegment

OPTIONS = ("--from", "--to", "--step", "--low", "--dwell", "--record", "--coarse")

levels = st.one_of(
    st.floats(min_value=0, max_value=100, allow_nan=False),
    st.sampled_from([0.0, 5.0, 10.0, 33.3333, 60.0, 60.0006, 99.9999, 100.0]),
    st.floats(allow_nan=True, allow_infinity=True),
)
step_sizes = st.one_of(
    st.floats(min_value=1e-3, max_value=150, allow_nan=False),
    st.sampled_from([20.0, 100.0, 7.0, 0.1, 0.0, -5.0, math.nan]),
)
dwells = st.one_of(
    st.floats(min_value=0.05, max_value=10, allow_nan=False), st.sampled_from([0.0, math.nan])
)


def _top(seg: RunSegment) -> float:
    if isinstance(seg, Ramp):
        return max(seg.start_pct, seg.end_pct)
    if isinstance(seg, Hold | Discharge):
        return seg.throttle_pct
    assert isinstance(seg, PackChange)
    return 0.0


def _build(kind: str, start: float, stop: float, step: float, dwell: float) -> plans.Plan:
    if kind == "steps":
        return plans.steps(start, stop, step, low=plans.Low(min(10.0, start), dwell), dwell_s=dwell)
    if kind == "stairs-up":
        return plans.stairs(start, stop, step, dwell_s=dwell)
    if kind == "stairs-down":
        return plans.stairs(start, stop, step, down=True, dwell_s=dwell)
    if kind == "ramp":
        return plans.ramp(start, stop, duration_s=max(dwell, 1e-3) * 10)
    assert kind == "explicit"
    return plans.explicit([start, stop], dwell_s=dwell)


def _refused_naming_an_option(exc: ConfigError) -> bool:
    return any(option in str(exc) for option in OPTIONS)


@settings(max_examples=1200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    kind=st.sampled_from(["steps", "stairs-up", "stairs-down", "ramp", "explicit"]),
    start=levels,
    stop=levels,
    step=step_sizes,
    dwell=dwells,
)
def test_no_level_above_to_on_any_fixed_plan(
    kind: str, start: float, stop: float, step: float, dwell: float
) -> None:
    try:
        plan = _build(kind, start, stop, step, dwell)
    except ConfigError as exc:
        if kind == "explicit":
            return  # an explicit plan's levels are checked by the CLI's --levels parser
        assert _refused_naming_an_option(exc), str(exc)
        return
    ceiling = max(start, stop) if kind == "explicit" else stop
    assert plan.ceiling_pct == ceiling
    tops = [_top(seg) for seg in plan.run_segments()]
    assert max(tops) <= ceiling, (kind, start, stop, step, tops)
    assert plan.max_throttle_pct <= ceiling
    if kind in ("stairs-up", "stairs-down", "ramp"):
        assert math.isclose(max(tops), stop)  # ends exactly at --to


@dataclass
class _Verdict:
    next_pct: float | None
    worst_pi_pct: float | None = 5.0
    target_met: bool = False
    next_reason: str = "random"
    next_pi_pct: float | None = 5.0
    note: str = ""
    move_to_v: float | None = None
    move_until_v: float | None = None
    move_rest_v: float | None = None

    @property
    def pi_at(self) -> Callable[[float, float], float | None]:
        return lambda thrust_n, voltage_v: 5.0


class _RandomChooser:
    """Proposes levels anywhere (below 0, inside, far above the range, NaN-free) and now and
    then asks for another voltage."""

    target_pi_pct = 1.0

    def __init__(self, seed: int) -> None:
        self.rng = random.Random(seed)

    def assess(
        self,
        points: object,
        voltage_v: float,
        throttle_range_pct: tuple[float, float] | None = None,
    ) -> _Verdict:
        r = self.rng.random()
        level = self.rng.choice(
            [self.rng.uniform(-20, 140), self.rng.uniform(0, 100), 100.0, 60.0006]
        )
        move = voltage_v * 0.9 if r < 0.1 else None
        return _Verdict(level, move_to_v=move, move_until_v=move, move_rest_v=move)

    def to_dict(self) -> dict[str, object]:
        return {}


def _adaptive_levels(plan: plans.Plan, rng: random.Random) -> Iterator[float]:
    assert plan.adaptive is not None
    elapsed = 0.0
    for seg in plan.run_segments():
        yield _top(seg)
        if isinstance(seg, PackChange):
            continue
        elapsed += 1.0
        level = _top(seg)
        point = SettledPoint(level, 0.1 * level, 24.0 - rng.random(), 1.0, 10, True, elapsed, 0.0)
        plan.adaptive.observe(
            point, {"max_thrust_n": rng.choice([5.0, 100.0]), "min_voltage_v": 18.0}
        )


@settings(max_examples=1000, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    start=levels,
    stop=levels,
    coarse=st.integers(min_value=0, max_value=8),
    dwell=dwells,
    seed=st.integers(min_value=0, max_value=2**16),
    across=st.booleans(),
)
def test_no_level_above_to_on_an_adaptive_plan(
    start: float, stop: float, coarse: int, dwell: float, seed: int, across: bool
) -> None:
    try:
        plan = plans.adaptive(
            _RandomChooser(seed),
            start,
            stop,
            coarse_levels=coarse,
            dwell_s=dwell,
            budget=plans.Budget(max_points=30),
            across=plans.AcrossVoltage((20.0, 25.0), lambda change: True) if across else None,
        )
    except ConfigError as exc:
        assert _refused_naming_an_option(exc), str(exc)
        return
    tops = list(_adaptive_levels(plan, random.Random(seed)))
    assert tops and max(tops) <= stop, (start, stop, tops)


@pytest.mark.parametrize(
    ("kind", "step", "want"),
    [
        ("stairs-up", "20", ["10.0", "30.0", "50.0", "60.0"]),
        ("stairs-down", "20", ["60.0", "50.0", "30.0", "10.0"]),
        ("stairs-up", "100", ["10.0", "60.0"]),
        ("steps", "100", ["10.0", "60.0", "10.0"]),
    ],
)
def test_sweep_dry_run_ends_at_to(tmp_path, kind: str, step: str, want: list[str]) -> None:
    """The issue's command: ``--to 60 --step 20`` planned 10/30/50/70 on 19a0a12."""
    cmd = [sys.executable, "-m", "thrustmap", "sweep", kind, "--stand", "sim://tyto-1585"]
    cmd += ["--throttle", "sim://betaflight", "--to", "60", "--step", step, "--dwell", "1"]
    cmd += ["--dry-run", "-o", str(tmp_path / "s.csv")]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    levels_seen = [line.split()[3] for line in out.stdout.splitlines() if " s  " in line]
    assert levels_seen == want
    assert "ceiling 60.0 %" in out.stdout


def test_steps_low_above_to_is_refused_naming_low(tmp_path) -> None:
    cmd = [sys.executable, "-m", "thrustmap", "sweep", "steps", "--stand", "sim://tyto-1585"]
    cmd += ["--throttle", "sim://betaflight", "--from", "2", "--to", "5", "--step", "1"]
    cmd += ["--dry-run", "-o", str(tmp_path / "s.csv")]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert out.returncode == 2
    assert "--low 10 % is above --to 5 %" in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1


def test_runner_never_commands_above_the_plan_ceiling() -> None:
    """Defence in depth: a plan built by hand with a segment above its ceiling is refused."""
    with pytest.raises(ConfigError, match="above --to 60"):
        plans.Plan("by-hand", (Hold(70.0, 1.0),), ceiling_pct=60.0)
