"""Adaptive: a short coarse pass, then each level where the map being fitted is least certain.

The recommended way to calibrate: the bench stops as soon as the map's 95 % prediction interval
is within TARGET_PI_PCT over the envelope (or a budget ends it), typically in a fraction of the
time and battery of the fixed experiments. Edit the constants below, then run:
    python scripts/adaptive.py --stand URL --throttle URL -o run.csv
With no URLs it runs on the built-in simulator in about a second. Every way out (completion, a
tripped limit, an error, Ctrl-C) stops the motor and verifies the stop; the log is kept and
marked with the outcome, and its sidecar says why each point was chosen and why the run ended.
"""

from __future__ import annotations

import thrustmap

# The range the plan may command, in % of the ESC's throttle range (PWM 1000..2000 µs).
FROM_PCT, TO_PCT = 10.0, 60.0
COARSE_LEVELS = 5  # the first pass: evenly spaced from FROM_PCT to TO_PCT
TARGET_PI_PCT = 1.0  # stop once the 95 % prediction interval is within this, % throttle
THRUST_RANGE_N = None  # the envelope (LO, HI) in N; None: what the coarse pass reached
MAX_MINUTES, MAX_WH = 10.0, None  # budgets: bench time, battery energy (None: no budget)
DWELL_S, RECORD_S = 3.0, 1.0  # each hold: until settled (at most DWELL_S), then RECORD_S more
MOTOR, ROTORS_ON_ESC = 1, 1  # the motor on the load cell (1-based); rotors on the ESC: 1 SR, 4 MR
LIMITS = thrustmap.Limits(max_throttle_pct=75.0, max_thrust_n=20.0, max_current_a=60.0)
# The devices: a serial port ("/dev/ttyUSB0", "COM3") or the built-in simulator (a Tyto 1585
# and a Betaflight FC, PWM 1000..2000 µs as in the paper, on one xNova 2207 / 6S bench).
STAND = "sim://tyto-1585?bench=script&drive_esc=0"
THROTTLE = f"sim://betaflight?bench=script&rotors={ROTORS_ON_ESC}&protocol=PWM"


def plan() -> thrustmap.plans.Plan:
    return thrustmap.plans.adaptive(
        thrustmap.MapChooser(TARGET_PI_PCT, thrust_range_n=THRUST_RANGE_N),
        FROM_PCT,
        TO_PCT,
        coarse_levels=COARSE_LEVELS,
        dwell_s=DWELL_S,
        record_s=RECORD_S,
        budget=thrustmap.plans.Budget(max_minutes=MAX_MINUTES, max_wh=MAX_WH),
    )


# The same few lines close every script on purpose: each one stays standalone (copy it anywhere).
def main(argv: list[str] | None = None) -> thrustmap.RunResult | None:
    return thrustmap.run_script(
        plan(),
        argv,
        limits=LIMITS,
        bench=thrustmap.ScriptBench(STAND, THROTTLE, MOTOR, ROTORS_ON_ESC),
        description=__doc__.splitlines()[0],
        emit=print,
        ask=input,
    )


if __name__ == "__main__":
    raise SystemExit(thrustmap.script_exit_code(main()))
