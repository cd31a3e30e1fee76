"""avenhaus/thrust_stand: an ESP32 (Arduino, PlatformIO ``lolin32``) with two HX711 load cells
(thrust and torque), an INA226, an optical rpm sensor and a web UI; it drives the ESC itself
(LEDC PWM, 1000-2000 µs at 50 Hz) and runs its own stepped test.

Written from ``src/main.cpp``, ``src/motor.cpp``, ``src/sensors.cpp`` and ``include/config.h``
at commit a1eb40a2b01369353d996fd5389337baf81a9d95 (lines below). Not compiled or run here (the
ESP32 web stack): checked against its print statements only -- "documentation/source only".

- 115200 baud (``config.h`` line 257, ``SERIAL_SPEED``). Boot lines start ``# `` (the
  ``DEBUG_print*`` macros, ``main.cpp`` lines 201-206) and a help menu follows
  (``print_help()``, lines 522-546).
- The live row (``loop()``, ``main.cpp`` lines 233-266), at most every 100 ms when the load
  cell has new data: ``<step> | Throttle: <%.1f>% | State: IDLE|RUNNING|ACCEL|DECEL |
  Thrust: <g> | Torque: <g·cm> | Voltage: <V> | Current: <A, 3 decimals> | Power: <W> |
  RPM: <rpm> | Thermal: <°C>C | Pot: <0..1>`` then three spaces and a CARRIAGE RETURN
  only (line 264: the line rewrites itself on a terminal). Cells are ``Name: value``
  (``cell_match``); Arduino's ``print(float)`` gives two decimals. Thrust is grams and torque
  the firmware's ``g·cm`` (both ``HX711_ADC::getData()`` with the calibration factors stored
  in NVS, ``sensors.cpp`` lines 143-144 and 177-178): converted exactly, 1 g = 9.80665e-3 N,
  1 g·cm = 9.80665e-5 N·m. The per-step summary lines of its own test (``print_stats()``,
  lines 368-385) have no ``State:`` cell and are not read as rows.
- Throttle from the host: single bytes (``check_serial()``, lines 296-336): ``1``..``9`` set
  10..90 %, ``0`` sets 100 % (``throttle_levels``: a request is sent as the highest level at
  or below it, below 10 % as the stop), each reached by a cosine ramp of 3 s per 100 %
  (``setThrottle()`` line 293, ``MotorESC::run()`` in ``motor.cpp`` lines 75-115); the
  throttle column is the ramp's present value.
- Stop: a space (line 314): outside a test the throttle ramps to 0 (3 s per 100 %: up to 3 s,
  ``stop_time_s``), inside one the test is aborted and the motor ramps down over
  ``decel_time_ms`` (3 s, ``config.h`` line 211). Confirmed by the throttle column reading 0.
- No watchdog on the serial link (only the web UI's throttle has a 5 s heartbeat,
  ``WEB_THROTTLE_TIMEOUT_MS``): if thrustmap dies the motor keeps its last throttle. thrustmap
  sends the space on every way out it controls; the ESC is on the stand, so no flight
  controller can stop it otherwise.
- Its own test (``s``, ``start_test()``/``run_test()``, lines 349-366 and 437-495): step 0 at
  rest, then 20 steps from 5 % to 100 % (``TEST_CONFIG_DEFAULT_*``, ``config.h`` lines
  208-215), each a 1 s ramp, 100 ms, then 2 s sampled; it ends with ``*** TEST RESULTS CSV
  DATA ***``, a CSV block in grams, g·cm, V, A, W, rpm and ``*** END OF TEST RESULTS ***``
  (``print_csv_results()``, lines 387-435). Read as a recording: the live rows carry the
  throttle; the block is kept as text.
"""

from __future__ import annotations

from thrustmap.core.physical import G0
from thrustmap.protocols.stands.line import Column, LineStandSpec

REPO = "avenhaus/thrust_stand"
COMMIT = "a1eb40a2b01369353d996fd5389337baf81a9d95"

#: grams-force and gram-force centimetres, exactly
N_PER_G = G0 / 1000.0
NM_PER_G_CM = G0 / 1000.0 / 100.0

#: the live row's cells (``main.cpp`` lines 235-263), by index after splitting on ``|``
ROW_CELLS = (
    "step",
    "Throttle",
    "State",
    "Thrust",
    "Torque",
    "Voltage",
    "Current",
    "Power",
    "RPM",
    "Thermal",
    "Pot",
)

PRESET = LineStandSpec(
    name="avenhaus-thrust-stand",
    columns={
        "throttle": Column(index=1),
        "thrust_n": Column(index=3, scale=N_PER_G),
        "torque_nm": Column(index=4, scale=NM_PER_G_CM),
        "voltage_v": Column(index=5),
        "current_a": Column(index=6),
        "rpm": Column(index=8),
    },
    delimiter="|",
    header_prefix=None,
    data_match=r"(?=-?\d+ \| Throttle: -?[\d.]+% \| State: )",
    cell_match=r":\s*(-?\d+(?:\.\d+)?)",
    throttle_scale="percent",
    throttle_levels=tuple((10.0 * k, str(k % 10)) for k in range(1, 11)),
    stop_command=" ",
    stop_time_s=3.0,
    baudrate=115200,
    sequence_start="s",
    sequence_end="*** END OF TEST RESULTS ***",
    line_patterns=(
        r"-?\d+ \| Throttle: -?\d+\.\d% \| State: (IDLE|RUNNING|ACCEL|DECEL) \| Thrust: "
        r"-?[\d.]+ \| Torque: -?[\d.]+ \| Voltage: -?[\d.]+ \| Current: -?[\d.]+ \| Power: "
        r"-?[\d.]+ \| RPM: -?[\d.]+ \| Thermal: (-?[\d.]+|nan|inf)C \| Pot: -?[\d.]+",
        r"-?\d+ \| Throttle: -?[\d.]+% \| Thrust: .* \| Valid: \d+ \|\s+\d+ \|\d+",
        r"Step,Throttle\(%\),Thrust\(g\),Torque\(g.{1,2}cm\),Voltage\(V\),.*",
        r"\d+(,-?[\d.]+|,nan|,inf){11}",
        r"# .*",
        r"\*\*\* .* \*\*\*",
        r"Arming ESC\.\.\.|ESC armed|Motor stopped",
        r"[\w-]{1,5} - .*",
        r"Press 's' to start the test, or 'h' to see this help message\.",
        r"Wi-Fi: .*",
    ),
    source=f"{REPO}@{COMMIT[:12]} src/main.cpp:199-336,387-435; src/motor.cpp:75-203; "
    "src/sensors.cpp:143-195; include/config.h:208-257",
    verified="documentation/source only: a recording built from the firmware's print "
    "statements, replayed in CI (not a run of the firmware)",
    description="avenhaus/thrust_stand (ESP32 + 2x HX711 + INA226, ESC on the stand): "
    "throttle in 10 % levels '1'..'0', ramped; a space stops (ramped, <= 3 s); no watchdog",
)
