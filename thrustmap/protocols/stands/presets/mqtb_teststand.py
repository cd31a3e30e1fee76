"""VirtualEnder/TestStandv2 (the MQTB stand): Energia on a TI Tiva C (TM4C123) LaunchPad, an
HX711 load cell, analog voltage and current sensors, a magnetic rpm sensor; it drives the ESC
itself (Oneshot125 from pin PB_4) and runs its own throttle programs.

Written from ``MQTB_Thrust_Stand/`` at commit 8521231b3d2d412c324d8562d2009fe1a6f4f835 (file and
line below). Not compiled or run here (TivaWare/Energia): checked against its print statements
only -- "documentation/source only".

- 921600 baud (``config.h`` line 6, ``UARTBAUD``). Between programs ``loop()`` sets the ESC to
  ``MINCOMMAND`` 1000 µs (``MQTB_Thrust_Stand.ino`` line 92), prints a two-line menu (lines
  100-101: ``Type: t(Tare), v(Battery Voltage), ...``) and waits for input; whatever arrives
  in one burst is echoed as ``Input: <text>`` (lines 110-111) and the first letter it contains
  in the order ``t c i b m r v w k s l z`` picks a program (lines 115-150).
- ``s`` (``steppingTest()``, ``testRoutines.ino`` lines 414-548) is this preset's sequence:
  ``Begining automated test, press any key to exit`` (line 421), 2 s, the header
  ``Time(uS),Throttle(uS),Thrust(g),eSteps,eRPMs,Volts,Amps`` (lines 424-440, the magnetic
  sensor fitted: ``MAGSENS`` true, ``OPTISENS`` false, ``config.h`` lines 13-14), then one row
  every ``LOOPDELAY`` 4000 µs (``config.h`` line 8; lines 492-509): µs since the start, the
  ESC µs, thrust in grams (``getThrust()``: an ``int`` of ``HX711::get_units()`` with the
  compiled scale ``LHSCALE`` -428 counts per gram, ``config.h`` line 35, and the tare at boot
  or ``t``: whole grams printed ``%.2f``), the step count, rpm (``calculateRPMs()``,
  ``sensorFunctions.ino`` lines 34-47, ``POLES`` 14), volts and amps (``%.2f``). The program:
  1100 µs for 2 s, 1100->2000 µs over 12 s, 2000 µs 0.5 s, 2000->1100 µs over 12 s, 1100 µs
  0.5 s (lines 453-457), then back to the menu (1000 µs). ``m`` (``mainTest()``, lines
  556-693) and ``k`` (``kvTest()``) print the same header and rows and are read the same way;
  ``b``, ``r`` and ``l`` print other columns and are not read by this preset.
- Throttle comes from the rows (``Throttle(uS)``, 1000..2000 µs); the host sends none.
- Stop: ANY byte ends a program (``while(!Serial.available())``, lines 461 and 544-547): the
  firmware drains the input, returns to ``loop()``, sets 1000 µs and prints the menu again --
  the menu's first line confirms the stop (``stop_confirm``). thrustmap sends ``e`` on every way
  out it controls: no program letter in the menu, and the key that EXITS the ESC calibration
  prompt (``calibrate()``, ``testRoutines.ino`` lines 62-69), where any other byte would go on
  to command full throttle.
- No watchdog: if thrustmap dies without sending the byte the program runs to its end (up to
  27 s, through full throttle) and then stops by itself. The ESC is on the stand, so no flight
  controller can stop it: keep a hand on the battery plug (or run the ESC from an FC and use
  the stand only to measure, ``--throttle``).
"""

from __future__ import annotations

from thrustmap.core.physical import G0
from thrustmap.protocols.stands.line import Column, LineStandSpec

REPO = "VirtualEnder/TestStandv2"
COMMIT = "8521231b3d2d412c324d8562d2009fe1a6f4f835"

#: the menu ``loop()`` prints before every program (``MQTB_Thrust_Stand.ino`` lines 100-101)
MENU = (
    "Type: t(Tare), v(Battery Voltage), w(Load Cell), c(Calibrate), s(Stepping Test)",
    "      b(Brake Test), r(Rate Test), k(KV Test), m(Main Test), or i(Idle)",
)
#: the test header with the magnetic rpm sensor (``testRoutines.ino`` lines 424-440)
HEADER = "Time(uS),Throttle(uS),Thrust(g),eSteps,eRPMs,Volts,Amps"
START_LINE = "Begining automated test, press any key to exit"

PRESET = LineStandSpec(
    name="mqtb-teststand",
    columns={
        "time_s": Column(index=0, scale=1e-6),
        "throttle": Column(index=1),
        "thrust_n": Column(index=2, scale=G0 / 1000.0),
        "rpm": Column(index=4),
        "voltage_v": Column(index=5),
        "current_a": Column(index=6),
    },
    delimiter=",",
    header_prefix=None,
    data_match=r"(?=-?\d+,-?\d+,)",
    throttle_scale="pwm",
    stop_command="e",
    stop_confirm=r"Type: t\(Tare\)",
    baudrate=921600,
    sequence_start="s",
    sequence_end=MENU[0],
    line_patterns=(
        r"\d{1,10},(1\d{3}|2000),-?\d+\.\d\d,\d+,-?\d+,-?\d+\.\d\d,-?\d+\.\d\d",
        r"Time\(uS\),Throttle\(uS\),Thrust\(g\),(eSteps,|oSteps,)+(eRPMs,|oRPMs,)+Volts,Amps",
        r"Type: t\(Tare\), v\(Battery Voltage\), w\(Load Cell\), c\(Calibrate\), "
        r"s\(Stepping Test\)",
        r"b\(Brake Test\), r\(Rate Test\), k\(KV Test\), m\(Main Test\), or i\(Idle\)",
        r"Input: .*",
        r"Begining automated (braking )?test, press any key to exit",
        r"Taring",
    ),
    source=f"{REPO}@{COMMIT[:12]} MQTB_Thrust_Stand/MQTB_Thrust_Stand.ino:92-150; "
    "testRoutines.ino:414-548; sensorFunctions.ino:3-47; config.h:6-40",
    verified="documentation/source only: a recording built from the firmware's print "
    "statements, replayed in CI (not a run of the firmware)",
    description="MQTB TestStandv2 (Tiva C + HX711, Oneshot125 ESC on the stand): runs its own "
    "programs ('s'); any byte stops them; no watchdog",
)
