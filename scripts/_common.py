"""What every bench script shares: arguments, the clock, the confirmation, the run, the outcome.

The scripts next to this file (steps.py, stairs_up.py, stairs_down.py, ramp.py) only describe
their experiment and call ``run_script``. Copy this file along with a script you move elsewhere.
"""

from __future__ import annotations

import argparse

from thrustmap.clock import Clock, MonotonicClock, SimClock
from thrustmap.rig import connect
from thrustmap.rig.interlocks import Limits
from thrustmap.rig.plans import Hold, Plan
from thrustmap.rig.runner import RunConfig, RunResult, Status, record_sweep
from thrustmap.rig.safety import terminate_as_exception

PROMPT = "Propellers on, stand secured, area clear? [y/N] "


def sim_urls(bench: str = "script", rotors_on_esc: int = 1) -> tuple[str, str]:
    """Default (stand, throttle) URLs: the built-in simulator, a Tyto 1585 and a Betaflight FC
    (PWM 1000..2000 µs, as in the paper) on one simulated xNova 2207 / 6S bench."""
    return (
        f"sim://tyto-1585?bench={bench}&drive_esc=0",
        f"sim://betaflight?bench={bench}&rotors={rotors_on_esc}&protocol=PWM",
    )


class Progress:
    """One line per finished plan segment: its level and the last reading (the runner calls
    this every control tick)."""

    def __init__(self, plan: Plan) -> None:
        self.plan = plan
        self.last: Status | None = None

    def __call__(self, st: Status) -> None:
        if self.last is not None and st.segment != self.last.segment:
            self.show(self.last)
        self.last = st

    def show(self, st: Status) -> None:
        seg = self.plan.segments[st.segment]
        level = f"{seg.throttle_pct:5.1f} %" if isinstance(seg, Hold) else f"-> {seg.end_pct:.1f} %"
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
        print(
            f"  {st.elapsed_s:6.1f} s  {st.segment + 1:>2}/{st.segments} {seg.label:<6} {level}: "
            + ", ".join(values)
        )


def run_script(
    plan: Plan,
    argv: list[str] | None,
    *,
    limits: Limits,
    stand_url: str,
    throttle_url: str,
    motor: int = 1,
    rotors_on_esc: int = 1,
    description: str = "",
) -> RunResult | None:
    """Parse ``--stand URL --throttle URL -o run.csv --yes``, ask "propellers on?" (unless
    ``--yes``), run ``plan`` with ``limits`` and record it. ``--throttle stand`` lets the stand
    drive the ESC. A simulated rig (every URL ``sim://`` or ``replay://``) runs on a SimClock,
    i.e. as fast as the computer goes; anything real on the monotonic clock. Returns None when
    the user declined."""
    ap = argparse.ArgumentParser(description=description or f"The {plan.name} experiment.")
    ap.add_argument("--stand", default=stand_url, help="stand URL: serial port, sim://, replay://")
    ap.add_argument("--throttle", default=throttle_url, help="FC URL, or 'stand' (its own ESC)")
    ap.add_argument("--calibration", help="calibration JSON of a real Tyto 1585")
    ap.add_argument("-o", "--output", default=f"{plan.name}.csv", help="the Ds log to write")
    ap.add_argument("--yes", action="store_true", help="do not ask whether the propellers are on")
    args = ap.parse_args(argv)
    print(plan.describe())
    urls = [args.stand] + ([] if args.throttle == "stand" else [args.throttle])
    clock: Clock = SimClock() if all(map(connect.is_simulated, urls)) else MonotonicClock()
    if not args.yes and input(PROMPT).strip().lower() not in ("y", "yes"):
        print("nothing spun")
        return None
    progress = Progress(plan)
    # SIGTERM unwinds like Ctrl-C, so the device exits below stop the motor on every way out.
    with (
        terminate_as_exception(),
        connect.open_stand(args.stand, clock, calibration=args.calibration) as stand,
    ):
        if args.throttle == "stand":
            output = connect.stand_esc_output(stand, motor - 1)
        else:
            output = connect.open_throttle_output(args.throttle, clock)
        with output:  # its exit stops the motor and verifies the stop, whatever happened
            result = record_sweep(
                plan,
                output,
                stand,
                args.output,
                clock,
                limits=limits,
                config=RunConfig(motor=motor - 1, rotors_on_esc=rotors_on_esc),
                monitor=progress,
            )
    if progress.last is not None:
        progress.show(progress.last)
    stop = "stop verified" if result.stop_verified else "STOP NOT VERIFIED: disconnect the battery"
    why = f" ({result.reason})" if result.reason else ""
    print(
        f"{result.status}{why}: {result.samples} samples in {result.duration_s:.1f} s; {stop}; "
        f"log {result.log_path}"
    )
    return result


def exit_code(result: RunResult | None) -> int:
    """0: completed (or declined), 3: aborted or the stop not verified (as ``thrustmap sweep``)."""
    if result is None or (result.status == "completed" and result.stop_verified):
        return 0
    return 3
