"""Stairs up: one level after another, lowest first (the paper's *-steps-up.csv).

Edit the constants below, then run:
    python scripts/stairs_up.py --stand URL --throttle URL -o run.csv
With no URLs it runs on the built-in simulator in about a second. ``--throttle stand`` lets the
stand drive the ESC itself. Every way out (completion, a tripped limit, an error, Ctrl-C)
stops the motor and verifies the stop; the log is kept and marked with the outcome.
"""

from __future__ import annotations

import thrustmap

# The experiment, in % of the ESC's throttle range (PWM 1000..2000 µs: 10 % = 1100 µs).
FROM_PCT, TO_PCT, STEP_PCT = 10.0, 60.0, 5.0  # the levels
DWELL_S = 3.0  # seconds on each level
REPEATS = 1  # run the whole staircase this many times
SETTLE, RECORD_S = False, 1.0  # True: a hold ends RECORD_S after thrust settles (dwell = max)
MOTOR, ROTORS_ON_ESC = 1, 1  # the motor on the load cell (1-based); rotors on the ESC: 1 SR, 4 MR
LIMITS = thrustmap.Limits(max_throttle_pct=75.0, max_thrust_n=20.0, max_current_a=60.0)
# The devices: a serial port ("/dev/ttyUSB0", "COM3") or the built-in simulator (a Tyto 1585
# and a Betaflight FC, PWM 1000..2000 µs as in the paper, on one xNova 2207 / 6S bench).
STAND = "sim://tyto-1585?bench=script&drive_esc=0"
THROTTLE = f"sim://betaflight?bench=script&rotors={ROTORS_ON_ESC}&protocol=PWM"


def plan() -> thrustmap.plans.Plan:
    return thrustmap.plans.stairs(
        FROM_PCT,
        TO_PCT,
        STEP_PCT,
        down=False,
        dwell_s=DWELL_S,
        settle=SETTLE,
        record_s=RECORD_S,
        repeats=REPEATS,
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
