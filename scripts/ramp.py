"""Ramp: a slow ramp up, a short hold at the top, the same ramp down (the paper's *-ramp.csv).

Edit the constants below, then run:
    python scripts/ramp.py --stand URL --throttle URL -o run.csv
With no URLs it runs on the built-in simulator in about a second. ``--throttle stand`` lets the
stand drive the ESC itself. Every way out (completion, a tripped limit, an error, Ctrl-C)
stops the motor and verifies the stop; the log is kept and marked with the outcome.
Up and down ramps in pairs cancel most of the rotor's lag; slower ramps leave less of it.
"""

from __future__ import annotations

import thrustmap

# The experiment, in % of the ESC's throttle range (PWM 1000..2000 µs: 70 % = 1700 µs).
FROM_PCT, TO_PCT = 0.0, 70.0  # bottom and top of the ramp
DURATION_S = 30.0  # seconds for each ramp (up, and again down)
HOLD_S = 1.0  # seconds at the bottom before and at the top between the ramps
REPEATS = 1  # up/down pairs
MOTOR, ROTORS_ON_ESC = 1, 1  # the motor on the load cell (1-based); rotors on the ESC: 1 SR, 4 MR
LIMITS = thrustmap.Limits(max_throttle_pct=75.0, max_thrust_n=20.0, max_current_a=60.0)
# The devices: a serial port ("/dev/ttyUSB0", "COM3") or the built-in simulator (a Tyto 1585
# and a Betaflight FC, PWM 1000..2000 µs as in the paper, on one xNova 2207 / 6S bench).
STAND = "sim://tyto-1585?bench=script&drive_esc=0"
THROTTLE = f"sim://betaflight?bench=script&rotors={ROTORS_ON_ESC}&protocol=PWM"


def plan() -> thrustmap.plans.Plan:
    return thrustmap.plans.ramp(
        FROM_PCT, TO_PCT, duration_s=DURATION_S, repeats=REPEATS, hold_s=HOLD_S
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
