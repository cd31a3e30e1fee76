"""alexeystn/tiny-thrust-stand: an Arduino Pro Mini, an HX711 (100 g cell), an INA139 current
sensor and a MOSFET driving a brushed whoop motor from pin 10 (``analogWrite``).

Written from ``Arduino/Tiny-Thrust-Stand/Tiny-Thrust-Stand.ino`` at commit
b028e455762a83da40422e2784b491120a0ba0ce (cited by line below) and the authors' reader
``Python/plot_thrust.py`` (the ADC scales):

- 115200 baud (``.ino`` line 44); nothing is printed until an ``S`` arrives (lines 50-52).
  Opening the port resets the Pro Mini (DTR on its auto-reset line): its bootloader hears
  nothing for a while, so the authors wait 2 s before sending ``S\r\n`` (``plot_thrust.py``
  lines 38-41); ``boot_s``.
- ``S`` starts the firmware's own sweep (line 53): duty 0, 10, ... 190 of 255 (``PWM_MAX`` 200,
  ``PWM_STEP`` 10, lines 11-12), each held 200 ms and then 10 rows (lines 56-65); then duty 0
  (line 67) and ``Done`` (line 68). The run is read as a recording: the throttle is the duty
  in each row, nothing is commanded during it.
- Rows: ``sprintf("%d\\t%d\\t%d\\t%d\\n", pwm, voltage, current, pull)`` (line 63): duty, raw
  10-bit ADC of the battery (A1) and of the INA139 (A0), and the HX711 reading ``>> 4``
  (line 62). On the AVR ``%d`` is a 16-bit int, so the 32-bit ``pull`` prints as its low
  16 bits, signed: the thrust column wraps every 65536 counts (``Column.modulo``); a
  calibration unwraps it around its tare (a 100 g cell at ~422 counts/g stays within ±77 g).
- Voltage ``5.0 / 1024`` V per count and current ``0.06 * 22 * 5.0 / 1024`` A per count are
  the authors' (``plot_thrust.py`` lines 15-16). Thrust: the authors' own cell read
  ``-1/422`` g per count (line 17, "experimental, inverted because thrust is directed
  upwards"); yours differs: ``thrustmap stand calibrate`` (tare + a known mass).
- No stop command and no watchdog: once started the sweep runs to its end (~26 s with the
  HX711 at 10 samples/s). The one way to stop it early is to reset the board: a DTR pulse on
  the Pro Mini's auto-reset line (``reset_stops``), which thrustmap sends on every way out.
"""

from __future__ import annotations

from thrustmap.core.physical import G0
from thrustmap.protocols.stands.line import Column, LineStandSpec

REPO = "alexeystn/tiny-thrust-stand"
COMMIT = "b028e455762a83da40422e2784b491120a0ba0ce"
SKETCH = "Arduino/Tiny-Thrust-Stand/Tiny-Thrust-Stand.ino"

#: the authors' cell: -1/422 g per count (plot_thrust.py line 17), in N per count
AUTHORS_N_PER_COUNT = -G0 / 1000.0 / 422.0

PRESET = LineStandSpec(
    name="tiny-thrust-stand",
    columns={
        "throttle": Column(index=0),
        "voltage_v": Column(index=1, scale=5.0 / 1024),
        "current_a": Column(index=2, scale=0.06 * 22 * 5.0 / 1024),
        "thrust_n": Column(index=3, scale=AUTHORS_N_PER_COUNT, modulo=65536),
    },
    delimiter="\t",
    header_prefix=None,
    throttle_scale="duty8",
    baudrate=115200,
    sequence_start="S\n",
    sequence_end="Done",
    # duty 0..190 step 10 (lines 11-12, 53); 200 ms (line 56) plus the dummy HX711 read
    # (line 58: one conversion, 0.1 s at 10 samples/s), then 10 rows, one per conversion
    sequence_levels=tuple(float(d) for d in range(0, 200, 10)),
    sequence_settle_s=0.3,
    sequence_rows=10,
    sequence_row_period_s=0.1,
    reset_stops=True,
    boot_s=2.0,  # opening the port resets the Pro Mini: the authors wait 2 s (plot_thrust.py:40)
    line_patterns=(r"1?\d{1,2}0?\t\d{1,4}\t\d{1,4}\t-?\d{1,5}", r"Done"),
    raw_counts=("thrust_n",),
    source=f"{REPO}@{COMMIT[:12]} {SKETCH}:44,50-68; Python/plot_thrust.py:15-17,38-41",
    verified="real firmware on a host shim (tests/support/arduino_shim), recording replayed in CI",
    description="tiny-thrust-stand (Arduino Pro Mini + HX711 + INA139, brushed motor): "
    "runs its own sweep on 'S'; no stop command, no watchdog: a DTR reset stops it",
)
