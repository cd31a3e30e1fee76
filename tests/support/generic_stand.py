"""A generic three-column line stand that drives its ESC, for the line-stand tests: the former
``stm32-hx711`` notes (that name is now an alias of the victorhook-thruststand preset, which
drives no ESC): ``millis, throttle_us, thrust`` at 921600 baud, an integer µs per line in."""

from __future__ import annotations

from thrustmap.protocols.stands.line import Column, LineStandSpec

GENERIC_3COL = LineStandSpec(
    name="generic-3col",
    columns={
        "time_s": Column(index=0, scale=1e-3),
        "throttle": Column(index=1),
        "thrust_n": Column(index=2),
    },
    header_prefix=None,
    throttle_scale="pwm",
    throttle_command="{us:d}\n",
    baudrate=921600,
)
