"""victorhook/thruststand: an STM32F103 "Blue Pill" (Arduino core, USB CDC) reading an HX711
through olkal/HX711_ADC 1.2.12; the motor is NOT driven by this board.

Written from ``src/main.cpp`` at commit ce197c86b910ae677a77a4001f3cb9709394fb98 (lines below),
``platformio.ini`` and the authors' host tools ``tools/device.py`` and ``tools/run.py``:

- 921600 baud (``main.cpp`` line 19). At boot ``LoadCell.start(2000, true)`` (line 21) settles
  for 2.4 s and tares: the thrust column is relative to the load at power-up.
- Every 10 ms (line 7, 28-31, 57): ``Serial.printf("%u, %u, %d\\n", now, throttle_us,
  (int) thrust)`` (line 55): ``millis()``, the throttle the host last sent, and
  ``LoadCell.getData()`` truncated to int (line 51) -- HX711_ADC with no ``setCalFactor``,
  so raw counts minus the boot tare, a moving average of 16 conversions (the library's
  ``SAMPLES``): with the HX711 at 10 samples/s the reading lags ~1.6 s, so hold each step
  longer than that. No header, no comments.
- In: a line; ``reboot`` resets the MCU (line 37-40), anything else is ``toInt()`` and
  constrained to 1000..2000 (lines 43-44) into ``throttle_us``, which is only printed back:
  the firmware has no PWM/ESC output. The authors' ``tools/run.py`` drives the motor through
  ArduPilot's ``MAV_CMD_DO_MOTOR_TEST`` and sends the same value to the stand as a label.
  So ``drives_esc`` is False: thrustmap drives and stops the motor through the flight
  controller (``--throttle``) and its interlocks; the stand has no watchdog and no stop.
- Thrust: the authors' figure is 220000 counts for 490 g (``tools/device.py`` lines 24-25,
  pull reads negative); yours differs: ``thrustmap stand calibrate`` (tare + a known mass).

This is the stand the older preset name ``stm32-hx711`` described (an alias of it now).
"""

from __future__ import annotations

from thrustmap.core.physical import G0
from thrustmap.protocols.stands.line import Column, LineStandSpec

REPO = "victorhook/thruststand"
COMMIT = "ce197c86b910ae677a77a4001f3cb9709394fb98"

#: the authors' cell: -490 g per 220000 counts (tools/device.py lines 24-25 and 60), N/count
AUTHORS_N_PER_COUNT = -490.0 / 220000.0 * G0 / 1000.0

ALIASES = ("stm32-hx711",)

PRESET = LineStandSpec(
    name="victorhook-thruststand",
    columns={
        "time_s": Column(index=0, scale=1e-3),
        "throttle": Column(index=1),
        "thrust_n": Column(index=2, scale=AUTHORS_N_PER_COUNT),
    },
    delimiter=",",
    row_separator=", ",
    header_prefix=None,
    throttle_scale="pwm",
    throttle_command="{us:d}\n",
    baudrate=921600,
    drives_esc=False,
    line_patterns=(r"\d{1,10}, (1\d{3}|2000), -?\d{1,8}",),
    raw_counts=("thrust_n",),
    source=f"{REPO}@{COMMIT[:12]} src/main.cpp:19-57; tools/device.py:24-25; tools/run.py",
    verified="real firmware (with olkal/HX711_ADC 1.2.12) on a host shim "
    "(tests/support/arduino_shim), recording replayed in CI",
    description="victorhook/thruststand (STM32 Blue Pill + HX711): measures only; the motor "
    "is driven and stopped by the flight controller; no stop command, no watchdog",
)
