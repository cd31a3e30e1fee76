"""einsz/whoop_thrust_stand: an RP2040 (USB CDC) with an HX711 or NAU7802 load cell, an INA226
power monitor and a bidirectional-DShot ESC it drives itself (telemetry schema 1).

Written from ``firmware/firmware.ino`` and ``firmware/config.h`` at commit
f06ef557a466c345b0ea27c1348ecf43dc551275 (read through the code index; functions and the
exact strings are cited below), ``docs/COLUMNS.md`` (commit 4a631d2319d7) and the authors'
emulator ``tools/fake_stand.py`` (same commit; line numbers of that file):

- Serial 115200 (``setup()``: ``Serial.begin(115200)``; USB CDC ignores it). Boot prints
  ``#INIT,...`` lines, then ``emitBanner()``: ``#SCHEMA,1``, ``#FW,thrust_stand,2.0.0,<date>``,
  ``#BOARD,rp2040``, ``#ESC,pin=..,proto=DSHOT600,poles=..,edt=..,dir=..``, ``#SCALE,...``,
  ``#INA,...``, ``#FLAGS,...``, ``#PHASE,...``, ``#AMBIENT,...`` and the header
  ``#COLS,t_us,phase,throttle_pct,dshot,rpm,erpm,erpm_raw,n_rpm,thrust_raw,n_thrust,
  thrust_age_us,bus_mv,bus_ua,shunt_uv,n_ina,ina_age_us,esc_temp_c,esc_stress,esc_dbg1,
  esc_dbg2,n_edt,edt_age_us,flags``; then the bare line ``SYSTEM_READY``. ``ID`` reprints the
  banner (a host that opened the port late missed it; this preset knows the columns anyway).
- Rows: ``emitSample()``: ``snprintf("D,%lu,%u,%d,%u,%ld,...,%u\\n", ...)``: ``D`` and the 23
  ``#COLS`` fields (``data_match`` ``D,``). 10 Hz at idle (``PRINT_IDLE_US = 100000`` in
  ``loop()``), 250 Hz (HX711) or 667 Hz (NAU7802) inside a sequence (``PRINT_FAST_US``).
  ``thrust_raw`` is TARED RAW COUNTS (``loadCellReadTared()``; "Conversion to grams is the
  host's job", config.h has no factor): ``raw_counts`` -- ``thrustmap stand calibrate``
  writes yours; until then the column's scale is the authors' emulated cell, -17155.7 counts
  per gram (``fake_stand.py`` line 110, ``SCALE_FACTOR``). ``bus_mv`` mV, ``bus_ua`` µA
  (INA226), ``rpm`` mechanical rpm (eRPM / (poles/2), ``rpmFromErpm()``), ``throttle_pct``
  the commanded percent, ``t_us`` ``micros()``.
- Commands (``handleCommand()``, one line each, 31 characters at most: ``inputBuf[32]``):
  a bare number ``NN`` sets the throttle in percent (``setThrottle(atoi(cmd))``,
  ``constrain(0, 100)``, DShot ``map(pct, 1, 100, 1, 2000)``) -- thrustmap sends the whole
  percent at or below the level asked (``{pct_floor}``); ``DSHOT,v`` a raw DShot value;
  ``STOP`` sets 0 at once, never ramped ("the path a person uses to stop a spinning
  propeller"), and aborts a running sequence; ``TARE`` (``#TARE,ok``); ``PING``. Unknown
  lines are ignored silently (no ``#ERR``); refusals print ``#ERROR,<what>``
  (``error_match``); inside a sequence every command but ``PING``/``STOP`` is refused with
  ``#ERROR,busy,<cmd>``.
- Watchdog (``serviceWatchdog()``, ``WATCHDOG_MS = 1000``): armed by the first ``PING``
  (``#WD,armed``); any command line feeds it (``lastHostMsgMs``); 1 s without one while the
  throttle is not 0 sets the throttle to 0, prints ``#WARN,watchdog_timeout``
  (``watchdog_match``) and aborts a sequence. thrustmap sends ``PING`` every 0.25 s. A second
  backstop on core 1 (``CORE0_STALL_MS = 500``) stops the motor if the firmware's own loop
  stalls.
- The firmware's own sequences: ``SWEEP`` (1 % steps from the lowest reliable idle to 100 %
  and back, 200 ms each, the last 100 ms logged; ``runSweepSequence()``), ``TRANSIENT``,
  ``RESPONSE,b,h,n``, ``COASTDOWN,p``, ``HOLD,p,log_ms,settle_ms``, ``DHOLD,...``: bracketed
  by ``START_<NAME>`` and ``END_<NAME>`` lines, the stop ramped (phase 8). ``thrustmap stand
  run`` sends ``SWEEP`` (``sequence_start``) and reads rows until ``END_SWEEP``, the throttle
  from each row.

Checked against the authors' emulator (``tools/fake_stand.py --serve`` on a pty, recorded
through ``record://``: ``fixtures/stands/einsz-whoop/``). The emulator has no watchdog (its
``PING`` does nothing): the watchdog is checked against this simulator, written from
``serviceWatchdog()``, not against the authors' code.
"""

from __future__ import annotations

from thrustmap.core.physical import G0
from thrustmap.protocols.stands.line import Column, LineStandSpec

REPO = "einsz/whoop_thrust_stand"
COMMIT = "f06ef557a466c345b0ea27c1348ecf43dc551275"

#: the ``#COLS`` banner of ``emitBanner()`` (and ``fake_stand.py`` lines 55-57)
COLUMNS = (
    "t_us",
    "phase",
    "throttle_pct",
    "dshot",
    "rpm",
    "erpm",
    "erpm_raw",
    "n_rpm",
    "thrust_raw",
    "n_thrust",
    "thrust_age_us",
    "bus_mv",
    "bus_ua",
    "shunt_uv",
    "n_ina",
    "ina_age_us",
    "esc_temp_c",
    "esc_stress",
    "esc_dbg1",
    "esc_dbg2",
    "n_edt",
    "edt_age_us",
    "flags",
)

#: the authors' emulated cell, -17155.7 counts per gram (``fake_stand.py`` line 110), in N/count
AUTHORS_N_PER_COUNT = G0 / 1000.0 / -17155.7

ALIASES = ("rp2040-whoop", "whoop-thrust-stand")

PRESET = LineStandSpec(
    name="einsz-whoop",
    columns={
        "time_s": Column(name="t_us", scale=1e-6),
        "throttle": Column(name="throttle_pct"),
        "rpm": Column(name="rpm"),
        "thrust_n": Column(name="thrust_raw", scale=AUTHORS_N_PER_COUNT),
        "voltage_v": Column(name="bus_mv", scale=1e-3),
        "current_a": Column(name="bus_ua", scale=1e-6),
    },
    delimiter=",",
    header_prefix="#COLS",
    header_names=COLUMNS,
    data_match=r"D,",
    throttle_scale="percent",
    throttle_command="{pct_floor:d}\n",
    stop_command="STOP\n",
    keepalive="PING\n",
    keepalive_interval_s=0.25,
    watchdog_s=1.0,
    watchdog_match=r"WARN,watchdog_timeout",
    error_match=r"ERROR,",
    baudrate=115200,
    sequence_start="SWEEP\n",
    sequence_end="END_SWEEP",
    line_patterns=(
        r"D(,-?\d{1,10}){23}",
        r"#[A-Z]{2,8}(,.*)?",
        r"SYSTEM_READY",
        r"(START|END)_[A-Z]+(,-?\d+)*",
        r"MIN_RELIABLE_IDLE,\d+",
    ),
    raw_counts=("thrust_n",),
    source=f"{REPO}@{COMMIT[:12]} firmware/firmware.ino: emitBanner(), emitSample(), "
    "handleCommand(), serviceWatchdog(), runSweepSequence(); tools/fake_stand.py:45-57,110",
    verified="authors' emulator (tools/fake_stand.py), recording replayed in CI; its "
    "watchdog from the firmware source only (the emulator has none)",
    description="einsz/whoop_thrust_stand (RP2040 + HX711/NAU7802 + INA226, bidirectional "
    "DShot): drives its ESC; PING every 0.25 s feeds its 1 s watchdog; STOP stops at once",
)
