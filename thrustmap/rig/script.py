"""What a bench script in ``scripts/`` calls: its arguments, the confirmation, the session.

A script describes its experiment (a plan, limits, device URLs) and calls ``run_script``; the
session (``rig.session``: devices, signals, clock, the verified stop) is the same one
``thrustmap sweep`` runs. The library does not print: the script passes ``emit`` (``print``)
and ``ask`` (``input``).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from thrustmap.rig.interlocks import Limits
from thrustmap.rig.plans import Plan
from thrustmap.rig.run_types import RunConfig, RunResult, Status
from thrustmap.rig.segments import Hold
from thrustmap.rig.session import BenchSession, Rig, choose_clock, exit_code, pairing_warnings

PROMPT = "Propellers on, stand secured, area clear? [y/N] "

__all__ = [
    "PROMPT",
    "SegmentLog",
    "run_script",
    "script_exit_code",
]


class SegmentLog:
    """One line per finished plan segment: its level and the last reading (the runner calls
    this every control tick; ``flush`` shows the last segment)."""

    def __init__(self, plan: Plan, emit: Callable[[str], None]) -> None:
        self.plan = plan
        self.emit = emit
        self.last: Status | None = None

    def __call__(self, st: Status) -> None:
        if st.phase != "plan":
            return
        if self.last is not None and st.segment != self.last.segment:
            self._show(self.last)
        self.last = st

    def flush(self) -> None:
        if self.last is not None:
            self._show(self.last)
            self.last = None

    def _show(self, st: Status) -> None:
        if st.segment < len(self.plan.segments):
            seg = self.plan.segments[st.segment]
            level = (
                f"{seg.throttle_pct:5.1f} %" if isinstance(seg, Hold) else f"-> {seg.end_pct:.1f} %"
            )
            label = seg.label
        else:  # an adaptive plan's level, chosen during the run
            level, label = f"{st.throttle_pct:5.1f} %", st.label.removesuffix("-settled")
        total = f"/{st.segments}" if st.segments else ""
        r = st.reading
        values = [
            f"{value:.{digits}f} {unit}"
            for value, digits, unit in (
                (r.thrust_n, 2, "N"),
                (r.voltage_v, 1, "V"),
                (r.current_a, 1, "A"),
                (r.rpm, 0, "rpm"),
            )
            if value is not None
        ]
        self.emit(
            f"  {st.elapsed_s:6.1f} s  {st.segment + 1:>2}{total} {label:<6} {level}: "
            + ", ".join(values)
            + (f"  [{st.plan_note}]" if st.plan_note else "")
        )


@dataclass(frozen=True)
class ScriptBench:
    """A script's default devices (``--stand`` and ``--throttle`` override the URLs), the motor
    on the load cell (1-based) and the rotors on its ESC (1: SR, 4: MR)."""

    stand_url: str
    throttle_url: str
    motor: int = 1
    rotors_on_esc: int = 1


def run_script(
    plan: Plan,
    argv: Sequence[str] | None,
    *,
    limits: Limits,
    bench: ScriptBench,
    description: str = "",
    emit: Callable[[str], None],
    ask: Callable[[str], str],
) -> RunResult | None:
    """Parse ``--stand URL --throttle URL --calibration cal.json -o run.csv --yes``, ask
    "propellers on?" (unless ``--yes``), run ``plan`` with ``limits`` in one bench session and
    record it. ``--throttle stand`` lets the stand drive the ESC.
    Returns None when the user declined (nothing was opened)."""
    motor, rotors_on_esc = bench.motor, bench.rotors_on_esc
    ap = argparse.ArgumentParser(description=description or f"The {plan.name} experiment.")
    ap.add_argument(
        "--stand", default=bench.stand_url, help="stand URL: serial port, sim://, replay://"
    )
    ap.add_argument(
        "--throttle", default=bench.throttle_url, help="FC URL, or 'stand' (its own ESC)"
    )
    ap.add_argument("--calibration", help="calibration JSON of a real Tyto 1585")
    ap.add_argument("-o", "--output", default=f"{plan.name}.csv", help="the Ds log to write")
    ap.add_argument("--yes", action="store_true", help="do not ask whether the propellers are on")
    args = ap.parse_args(None if argv is None else list(argv))
    rig = Rig(
        stand=args.stand, throttle=args.throttle, calibration=args.calibration, motor=motor - 1
    )
    emit(plan.describe())
    clock = choose_clock(rig.urls())
    for warning in pairing_warnings(rig):
        emit(f"warning: {warning}")
    if not args.yes and ask(PROMPT).strip().lower() not in ("y", "yes"):
        emit("nothing spun")
        return None
    progress = SegmentLog(plan, emit)
    session = BenchSession(rig, clock)
    with session:
        result = session.sweep(
            plan,
            args.output,
            limits=limits,
            config=RunConfig(motor=motor - 1, rotors_on_esc=rotors_on_esc),
            monitor=progress,
        )
    result.stop_verified = result.stop_verified and session.stop_verified is not False
    progress.flush()
    stop = "stop verified" if result.stop_verified else "STOP NOT VERIFIED: disconnect the battery"
    why = f" ({result.reason})" if result.reason else ""
    emit(
        f"{result.status}{why}: {result.samples} samples in {result.duration_s:.1f} s; {stop}; "
        f"log {result.log_path}"
    )
    return result


def script_exit_code(result: RunResult | None) -> int:
    """The exit code of a script (the scheme of ``thrustmap sweep``; 0 when declined)."""
    return 0 if result is None else exit_code(result.outcome, result.stop_verified)
