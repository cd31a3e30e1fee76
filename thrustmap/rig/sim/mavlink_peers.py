"""PX4-like and ArduPilot-like vehicles that speak MAVLink 2 (via pymavlink) over bytes.

Both are ``BytePeer``s (``sim://px4``, ``sim://ardupilot``, or ``SimSerial(PX4Vehicle(plant),
clock)``) and forward motor commands to a ``Plant``. Behaviour follows the MAVLink
specification and what real SITL builds were seen to do (checked in tests/test_rig_fc_firmware.py
against recordings of them):

PX4 (autopilot 12), as PX4 v1.17 SITL behaves
- Parameters: INT32 ones (COM_MOT_TEST_EN, CA_ROTOR_COUNT, PWM_MAIN_*) are sent BYTEWISE (the
  integer's bytes in the float field), announced by AUTOPILOT_VERSION capabilities 59647 (bit
  PARAM_ENCODE_BYTEWISE); an unknown name gets PARAM_ERROR. Output limits are per output:
  PWM_MAIN_FUNC1..8 (101 = Motor1 ...), PWM_MAIN_MIN<n>/MAX<n>/DIS<n> (disarmed 900 µs); the
  old PWM_MAIN_MIN/MAX/DIS exist only with ``legacy_pwm=True`` (older firmware).
- Telemetry flood (``flood=True``): ATTITUDE, ATTITUDE_QUATERNION, LOCAL_POSITION_NED,
  GLOBAL_POSITION_INT, POSITION_TARGET_LOCAL_NED and ATTITUDE_TARGET at 50 Hz each, as the GCS
  link streams them by default (about 15 kB/s).
- MAV_CMD_DO_MOTOR_TEST -> UNSUPPORTED (current PX4).
- MAV_CMD_ACTUATOR_TEST: DENIED while armed, with the safety button on, or COM_MOT_TEST_EN != 1;
  p5 = MOTOR1..16 (SERVO1..16 = 33..48 are accepted and drive no motor); timeout 0 or > 3 s -> 3 s;
  NaN stops; the motor stops by itself at the timeout. The value passes through THR_MDL_FAC
  (inverse of rel_thrust = f·u² + (1-f)·u) before reaching the plant; negative values idle.
- Streams: SYS_STATUS, BATTERY_STATUS (per-cell), ESC_STATUS, SERVO_OUTPUT_RAW.
- Sim choice: a motor number beyond the plant's motor count is DENIED.

ArduPilot / ArduCopter (autopilot 3), as ArduCopter 4.7 SITL behaves
- Integer parameters are sent as float values (C cast); capabilities 64495 (no bytewise bit).
- Motor numbering: p1 is a TEST-ORDER number; the frame's table (FRAME_CLASS/FRAME_TYPE, quad X
  by default) maps it to the FC motor (Motor N drives output N and plant motor N-1).
- Every accepted DO_MOTOR_TEST that finds no test running STARTS one ("starting motor test",
  armed), including a "stop" (PWM 0, timeout 0), which then ends at once ("finished motor
  test"). ``init_delay_s``: for that long after boot every test is refused with FAILED and
  "Motor Test: Board initialising", and SERVO_OUTPUT_RAW / BATTERY_STATUS are not sent yet.
- MAV_CMD_DO_MOTOR_TEST: preconditions board initialised, RC calibrated (unless p2 = PWM), landed,
  safety switch not engaged; failure -> FAILED plus STATUSTEXT "Motor Test: ...". While a test
  runs HEARTBEAT says ARMED. A new command during a test skips the checks, overwrites the
  throttle and restarts the timer. Timeout 0, or a PWM outside 800..2200, stops the test (the
  command itself is ACCEPTED). Timeout is capped at 600 s; at the timeout the test stops and
  the vehicle disarms. p5 motor count > 1 runs motors p1.. p1+count-1 one after another, each
  for the timeout. p1 is a test-order number mapped through ``test_order`` to a plant motor.
- PERCENT maps linearly to MOT_PWM_MIN..MOT_PWM_MAX; PILOT uses ``rc_throttle_fraction``.
- MAV_CMD_ACTUATOR_TEST -> UNSUPPORTED.
- Streams: SYS_STATUS, BATTERY_STATUS (total in voltages[0]), ESC_TELEMETRY_1_TO_4, SERVO_OUTPUT_RAW.

Registration: importing this module registers ``px4`` and ``ardupilot`` with
``thrustmap.protocols.peer`` using a ``ConstantPlant``; call ``register_mavlink_peers(factory,
replace=True)`` to put a physics plant behind them. URL options: ``motors`` (4), ``sysid`` (1),
``rate_hz`` (10), PX4 ``armed``/``safety``/``com_mot_test_en``/``thr_mdl_fac``/``legacy_pwm``/
``flood``/``cells`` (default: the plant's pack), ArduPilot ``landed``/``safety``/``rc_calibrated``/``frame_class``/``frame_type``/
``init_delay_s``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from thrustmap.protocols.mavlink import codec as mav
from thrustmap.protocols.mavlink import encode as enc
from thrustmap.protocols.mavlink.frames import motor_order
from thrustmap.protocols.mavlink.params import ParamEncoding, ParamType
from thrustmap.protocols.mavlink.signing import parse_signing_key
from thrustmap.protocols.peer import BytePeer, register_peer
from thrustmap.rig.sim.mavlink_vehicle import SimMavlinkVehicle
from thrustmap.rig.sim.options import MAX_SIM_MOTORS, opt_flag, opt_float, opt_int
from thrustmap.rig.sim.plant import ConstantPlant, Plant, PlantState

R = mav.MavResult
MSG_SYS_STATUS = 1
MSG_SERVO_OUTPUT_RAW = 36
MSG_BATTERY_STATUS = 147
MSG_ESC_STATUS = 291
MSG_ESC_TELEMETRY_1_TO_4 = 11030


def _servo_raw(vehicle: SimMavlinkVehicle, outputs_us: Sequence[int]) -> Any:
    return enc.servo_output_raw_message(vehicle.time_since_boot_s, outputs_us)


def _sys_status(state: PlantState) -> Any:
    return enc.sys_status_message(state.voltage_v, state.current_a)


# ---------------------------------------------------------------------------------------------
# PX4
# ---------------------------------------------------------------------------------------------
PX4_OUTPUTS = 8
FLOOD_RATE_HZ = 50.0


class PX4Vehicle(SimMavlinkVehicle):
    autopilot = mav.Autopilot.PX4
    param_encoding = ParamEncoding.BYTEWISE
    param_error_for_unknown = True
    capabilities = 59647  # PX4 v1.17 SITL: includes PARAM_ENCODE_BYTEWISE (16)
    flight_sw_version = 17891392  # 1.17.0-dev

    def __init__(
        self,
        plant: Plant,
        *,
        armed: bool = False,
        safety_on: bool = False,
        cells: int | None = None,
        motors: int | None = None,
        legacy_pwm: bool = False,
        flood: bool = False,
        **kwargs: Any,
    ) -> None:
        self.pilot_armed = armed
        self.safety_on = safety_on
        #: the battery's cells: as given, else the plant's pack (its voltage must match them)
        self.cells = cells if cells is not None else plant_cells(plant)
        #: the vehicle's motors (its frame: 4 for the SIH quadx); the plant may hold fewer
        #: rotors (one on the stand): motors beyond them drive nothing
        self.motor_count = motors if motors is not None else max(4, plant.motor_count)
        self.legacy_pwm = legacy_pwm
        self.flood = flood
        self._tests: dict[int, tuple[float, float]] = {}  # motor -> (fraction, deadline_s)
        super().__init__(plant, **kwargs)
        if flood:
            period_s = 1.0 / FLOOD_RATE_HZ
            for message_id, builder in self._flood_streams().items():
                self._streams[message_id] = (builder, period_s)
                self._default_periods[message_id] = period_s
                self.catch_up_streams.add(message_id)

    def default_params(self) -> Mapping[str, float]:
        params = {
            "COM_MOT_TEST_EN": 1.0,
            "THR_MDL_FAC": 0.0,
            "MC_BAT_SCALE_EN": 0.0,
            "CA_ROTOR_COUNT": float(self.motor_count),
        }
        for ch in range(1, PX4_OUTPUTS + 1):
            is_motor = ch <= self.motor_count
            params[f"PWM_MAIN_FUNC{ch}"] = float(100 + ch) if is_motor else 0.0
            params[f"PWM_MAIN_MIN{ch}"] = 1000.0
            params[f"PWM_MAIN_MAX{ch}"] = 2000.0
            params[f"PWM_MAIN_DIS{ch}"] = 900.0
        if self.legacy_pwm:
            params.update({"PWM_MAIN_MIN": 1000.0, "PWM_MAIN_MAX": 2000.0, "PWM_MAIN_DIS": 900.0})
        return params

    def default_param_types(self) -> Mapping[str, int]:
        return {
            name: ParamType.INT32
            for name in self.default_params()
            if name != "THR_MDL_FAC"  # the only REAL32 here
        }

    def _flood_streams(self) -> dict[int, Callable[[PlantState], list[Any]]]:
        def t() -> int:
            return round(self.time_since_boot_s * 1000) & 0xFFFFFFFF

        return {
            30: lambda s: [mavlink2.MAVLink_attitude_message(t(), 0.01, -0.02, 1.5, 0, 0, 0)],
            31: lambda s: [mavlink2.MAVLink_attitude_quaternion_message(t(), 1, 0, 0, 0, 0, 0, 0)],
            32: lambda s: [mavlink2.MAVLink_local_position_ned_message(t(), 0, 0, 0, 0, 0, 0)],
            33: lambda s: [
                mavlink2.MAVLink_global_position_int_message(
                    t(), 473977418, 85455940, 488000, 0, 0, 0, 0, 0
                )
            ],
            85: lambda s: [
                mavlink2.MAVLink_position_target_local_ned_message(
                    t(), 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0
                )
            ],
            83: lambda s: [
                mavlink2.MAVLink_attitude_target_message(t(), 0, [1, 0, 0, 0], 0, 0, 0, 0)
            ],
        }

    @property
    def armed(self) -> bool:
        return self.pilot_armed

    def running_motors(self) -> dict[int, float]:
        return {motor: fraction for motor, (fraction, _) in self._tests.items()}

    def telemetry_streams(self) -> Mapping[int, Callable[[PlantState], list[Any]]]:
        return {
            MSG_SYS_STATUS: lambda s: [_sys_status(s)],
            MSG_BATTERY_STATUS: lambda s: [
                enc.battery_status_message([s.voltage_v / self.cells] * self.cells, s.current_a)
            ],
            MSG_ESC_STATUS: self._esc_status,
            MSG_SERVO_OUTPUT_RAW: lambda s: [_servo_raw(self, self.outputs_us())],
        }

    def _esc_status(self, state: PlantState) -> list[Any]:
        missing = max(0, self.motor_count - len(state.rpm))  # motors off the stand: at rest
        rpm = list(state.rpm) + [0.0] * missing
        current = list(state.motor_current_a) + [0.0] * missing
        return [
            enc.esc_status_message(
                first_index=first,
                time_s=self.time_since_boot_s,
                rpm=rpm[first : first + 4],
                voltage_v=[state.voltage_v] * len(rpm[first : first + 4]),
                current_a=current[first : first + 4],
            )
            for first in range(0, max(1, len(rpm)), 4)
        ]

    def outputs_us(self) -> list[int]:
        """All 8 main outputs, as PX4 reports them (disarmed value where no test runs)."""
        out = []
        for ch in range(1, PX4_OUTPUTS + 1):
            lo, hi, dis = (
                self.params.get(f"PWM_MAIN_{k}{ch}", self.params.get(f"PWM_MAIN_{k}", default))
                for k, default in (("MIN", 1000.0), ("MAX", 2000.0), ("DIS", 900.0))
            )
            motor = int(self.params[f"PWM_MAIN_FUNC{ch}"]) - 101
            if motor in self._tests:
                out.append(round(lo + (hi - lo) * self._tests[motor][0]))
            else:
                out.append(round(dis))
        return out

    def update(self, now_s: float) -> None:
        for motor, (_, deadline_s) in sorted(self._tests.items()):
            if deadline_s <= now_s:
                self._stop(motor, deadline_s)

    def _stop(self, motor: int, time_s: float) -> None:
        self._tests.pop(motor, None)
        if motor < self.plant.motor_count:  # motors beyond the stand's drive nothing
            self.set_plant_throttle(motor, 0.0, time_s)

    def _fraction(self, value: float) -> float:
        """Inverse of PX4's thrust model rel_thrust = f·u² + (1-f)·u (THR_MDL_FAC = f)."""
        thrust = min(max(value, 0.0), 1.0)
        f = min(max(self.params["THR_MDL_FAC"], 0.0), 1.0)
        if f < 1e-9:
            return thrust
        return (-(1.0 - f) + math.sqrt((1.0 - f) ** 2 + 4.0 * f * thrust)) / (2.0 * f)

    def handle_command(self, command: mav.CommandLong, now_s: float) -> int:
        if command.command == mav.MAV_CMD_DO_MOTOR_TEST:
            return R.UNSUPPORTED
        if command.command != mav.MAV_CMD_ACTUATOR_TEST:
            return R.UNSUPPORTED
        value, timeout_s, _, _, function_f = command.params[:5]
        if self.pilot_armed or self.safety_on or self.params["COM_MOT_TEST_EN"] != 1.0:
            return R.DENIED
        function = int(function_f)
        if 33 <= function <= 48:
            return R.ACCEPTED  # a servo: nothing on the stand
        motor = function - 1
        if not 0 <= motor < min(16, self.motor_count):
            return R.DENIED
        if math.isnan(value):
            self._stop(motor, now_s)
            return R.ACCEPTED
        if not 0.0 < timeout_s <= mav.PX4_ACTUATOR_TEST_MAX_TIMEOUT_S or math.isnan(timeout_s):
            timeout_s = mav.PX4_ACTUATOR_TEST_MAX_TIMEOUT_S
        fraction = self._fraction(value)
        self._tests[motor] = (fraction, now_s + timeout_s)
        if motor < self.plant.motor_count:
            self.set_plant_throttle(motor, fraction, now_s)
        return R.ACCEPTED


# ---------------------------------------------------------------------------------------------
# ArduPilot
# ---------------------------------------------------------------------------------------------
@dataclass
class _MotorTest:
    first_seq: int  # 1-based test-order number
    count: int
    throttle_type: int
    value: float
    timeout_s: float
    start_s: float


class ArduPilotVehicle(SimMavlinkVehicle):
    autopilot = mav.Autopilot.ARDUPILOT
    capabilities = 64495  # ArduCopter 4.7 SITL: no PARAM_ENCODE_BYTEWISE (C cast)
    flight_sw_version = 67567616  # 4.7.0-dev
    accepts_setup_signing = True  # GCS_Signing.cpp: on any port (unsigned on the first)

    def __init__(
        self,
        plant: Plant,
        *,
        initialised: bool = True,
        landed: bool = True,
        safety_switch_engaged: bool = False,
        rc_calibrated: bool = True,
        rc_throttle_fraction: float = 0.0,
        test_order: Sequence[int] | None = None,
        frame_class: int = 1,
        frame_type: int = 1,
        init_delay_s: float = 0.0,
        **kwargs: Any,
    ) -> None:
        self.frame_class = frame_class
        self.frame_type = frame_type
        self.init_delay_s = init_delay_s
        self.tests_started = 0  # motor tests started (a stop sent while idle counts)
        self.initialised = initialised
        self.landed = landed
        self.safety_switch_engaged = safety_switch_engaged
        self.rc_calibrated = rc_calibrated
        self.rc_throttle_fraction = rc_throttle_fraction
        if test_order is None:  # test order n -> FC motor, from the frame's table
            order = motor_order(frame_class, frame_type, plant.motor_count)
            test_order = [order.motor_for(n) for n in range(1, order.motor_count + 1)]
        self.test_order = list(test_order)
        self._test: _MotorTest | None = None
        self._running: int | None = None  # plant motor spinning now
        self._running_pwm = 0
        super().__init__(plant, **kwargs)

    def default_params(self) -> Mapping[str, float]:
        return {
            "MOT_PWM_MIN": 1000.0,
            "MOT_PWM_MAX": 2000.0,
            "MOT_THST_EXPO": 0.65,
            "MOT_SPIN_MIN": 0.15,
            "MOT_SPIN_MAX": 0.95,
            "MOT_SPIN_ARM": 0.10,
            "MOT_THST_HOVER": 0.35,
            "MOT_BAT_VOLT_MAX": 0.0,
            "MOT_BAT_VOLT_MIN": 0.0,
            "MOT_PWM_TYPE": 0.0,
            "FRAME_CLASS": float(self.frame_class),
            "FRAME_TYPE": float(self.frame_type),
        }

    def default_param_types(self) -> Mapping[str, int]:
        return {
            "MOT_PWM_MIN": ParamType.INT16,
            "MOT_PWM_MAX": ParamType.INT16,
            "MOT_PWM_TYPE": ParamType.INT8,
            "FRAME_CLASS": ParamType.INT8,
            "FRAME_TYPE": ParamType.INT8,
        }

    @property
    def armed(self) -> bool:
        return self._test is not None

    @property
    def booting(self) -> bool:
        """Within ``init_delay_s`` of boot: motor tests refused, no outputs or battery sent."""
        return not self.initialised or self.time_since_boot_s < self.init_delay_s

    @property
    def motor_test_running(self) -> bool:
        return self._test is not None

    def telemetry_streams(self) -> Mapping[int, Callable[[PlantState], list[Any]]]:
        return {
            MSG_SYS_STATUS: lambda s: [_sys_status(s)],
            MSG_BATTERY_STATUS: lambda s: (
                [] if self.booting else [enc.battery_status_message([s.voltage_v], s.current_a)]
            ),
            MSG_ESC_TELEMETRY_1_TO_4: lambda s: [
                enc.esc_telemetry_message(
                    rpm=s.rpm[:4],
                    voltage_v=[s.voltage_v] * min(4, len(s.rpm)),
                    current_a=s.motor_current_a[:4],
                    temperature_c=s.temperature_c[:4],
                )
            ],
            MSG_SERVO_OUTPUT_RAW: lambda s: (
                [] if self.booting else [_servo_raw(self, self.outputs_us())]
            ),
        }

    def outputs_us(self) -> list[int]:
        """One output per FC motor (Motor n on output n); the plant holds the first ones."""
        idle = round(self.params["MOT_PWM_MIN"])
        out = [idle] * max(len(self.test_order), self.plant.motor_count)
        if self._running is not None:
            out[self._running] = self._running_pwm
        return out

    def _pwm(self, test: _MotorTest) -> float:
        lo, hi = self.params["MOT_PWM_MIN"], self.params["MOT_PWM_MAX"]
        if test.throttle_type == mav.MotorTestThrottleType.PWM:
            return test.value
        if test.throttle_type == mav.MotorTestThrottleType.PILOT:
            return lo + (hi - lo) * min(max(self.rc_throttle_fraction, 0.0), 1.0)
        return lo + (hi - lo) * min(max(test.value, 0.0), 100.0) / 100.0  # PERCENT, COMPASS_CAL

    def _output(self, motor: int | None, pwm: int, time_s: float) -> None:
        on_stand = self.plant.motor_count  # FC motors beyond the stand's drive nothing
        if self._running is not None and self._running != motor and self._running < on_stand:
            self.set_plant_throttle(self._running, 0.0, time_s)
        self._running, self._running_pwm = motor, pwm
        if motor is not None and motor < on_stand:
            lo, hi = self.params["MOT_PWM_MIN"], self.params["MOT_PWM_MAX"]
            self.set_plant_throttle(motor, min(max((pwm - lo) / (hi - lo), 0.0), 1.0), time_s)

    def stop_test(self, time_s: float) -> None:
        self._output(None, 0, time_s)
        if self._test is not None:
            self.send(enc.statustext_message("finished motor test", mav.Severity.INFO))
        self._test = None

    def update(self, now_s: float) -> None:
        test = self._test
        if test is None:
            return
        pwm = self._pwm(test)
        lo_ok, hi_ok = mav.ARDUPILOT_MOTOR_TEST_PWM_RANGE_US
        if test.timeout_s <= 0 or not lo_ok <= pwm <= hi_ok:
            self.stop_test(test.start_s)
            return
        step = int((now_s - test.start_s) // test.timeout_s)
        if step >= test.count:
            self.stop_test(test.start_s + test.count * test.timeout_s)
            return
        seq = test.first_seq + step
        motor = self.test_order[seq - 1] if 1 <= seq <= len(self.test_order) else None
        if motor != self._running or round(pwm) != self._running_pwm:
            self._output(motor, round(pwm), test.start_s + step * test.timeout_s)

    def _precondition_failure(self, throttle_type: int) -> str | None:
        if self.booting:
            return "Board initialising"
        if throttle_type != mav.MotorTestThrottleType.PWM and not self.rc_calibrated:
            return "RC not calibrated"
        if not self.landed:
            return "vehicle not landed"
        if self.safety_switch_engaged:
            return "Safety switch"
        return None

    def handle_command(self, command: mav.CommandLong, now_s: float) -> int:
        if command.command != mav.MAV_CMD_DO_MOTOR_TEST:
            return R.UNSUPPORTED
        seq_f, type_f, value, timeout_s, count_f = command.params[:5]
        throttle_type = int(type_f)
        if self._test is None:
            why = self._precondition_failure(throttle_type)
            if why is not None:
                self.send(enc.statustext_message(f"Motor Test: {why}", mav.Severity.CRITICAL))
                return R.FAILED
            # Even a "stop" starts a test when none runs (it then ends at once).
            self.tests_started += 1
            self.send(enc.statustext_message("starting motor test", mav.Severity.INFO))
        if math.isnan(timeout_s) or math.isnan(value):
            timeout_s = 0.0
        self._test = _MotorTest(
            first_seq=int(seq_f),
            count=max(1, int(count_f)),
            throttle_type=throttle_type,
            value=value,
            timeout_s=min(max(timeout_s, 0.0), mav.ARDUPILOT_MOTOR_TEST_MAX_TIMEOUT_S),
            start_s=now_s,
        )
        self._running_pwm = -1  # force the new throttle out even on the same motor
        self.update(now_s)
        return R.ACCEPTED


# ---------------------------------------------------------------------------------------------
# sim:// registration
# ---------------------------------------------------------------------------------------------
PlantFactory = Callable[[Mapping[str, str]], Plant]


#: a LiPo cell's highest resting voltage: a pack of V volts has at least V / this cells
_LIPO_FULL_CELL_V = 4.35


def plant_cells(plant: Plant) -> int:
    """The cells of the battery behind ``plant``: the physics preset's, else the fewest LiPo
    cells its voltage can come from (16.8 V: 4S; 24.9 V: 6S)."""
    params = getattr(plant, "params", None)
    cells = getattr(params, "cells", None)
    if isinstance(cells, int) and cells >= 1:
        return cells
    voltage_v = plant.state(0.0).voltage_v
    return max(1, math.ceil(voltage_v / _LIPO_FULL_CELL_V))


def constant_plant(options: Mapping[str, str]) -> Plant:
    return ConstantPlant(motor_count=opt_int(options, "motors", 4, lo=1, hi=MAX_SIM_MOTORS))


def _flag(options: Mapping[str, str], key: str, default: bool) -> bool:
    return opt_flag(options, key, default)


def _common(options: Mapping[str, str]) -> dict[str, Any]:
    """Options every simulated vehicle takes. ``signing_key_file=PATH``: sign with the key in
    that file (a path, so the key never appears in a URL or a transcript header);
    ``accept_unsigned=1``: take unsigned messages too (ArduPilot's first port)."""
    key = None
    if options.get("signing_key_file"):
        key = parse_signing_key(options["signing_key_file"], source="signing_key_file")
    return {
        "system_id": opt_int(options, "sysid", 1, lo=1, hi=255),
        "telemetry_rate_hz": opt_float(
            options, "rate_hz", 10.0, positive=True, maximum=1000.0, what="a telemetry rate in Hz"
        ),  # fmt: skip
        "signing_key": key,
        "accept_unsigned": _flag(options, "accept_unsigned", False),
    }


def px4_from_options(options: Mapping[str, str], plant: Plant | None = None) -> PX4Vehicle:
    params = {}
    if "com_mot_test_en" in options:
        params["COM_MOT_TEST_EN"] = opt_float(options, "com_mot_test_en", 0.0)
    if "thr_mdl_fac" in options:
        params["THR_MDL_FAC"] = opt_float(options, "thr_mdl_fac", 0.0, minimum=0.0, maximum=1.0)
    return PX4Vehicle(
        plant if plant is not None else constant_plant(options),
        armed=_flag(options, "armed", False),
        safety_on=_flag(options, "safety", False),
        legacy_pwm=_flag(options, "legacy_pwm", False),
        flood=_flag(options, "flood", False),
        cells=opt_int(options, "cells", 0, lo=1, hi=14) if "cells" in options else None,
        motors=opt_int(options, "motors", 4, lo=1, hi=MAX_SIM_MOTORS)
        if "motors" in options
        else None,
        params=params,
        **_common(options),
    )


def ardupilot_from_options(
    options: Mapping[str, str], plant: Plant | None = None
) -> ArduPilotVehicle:
    return ArduPilotVehicle(
        plant if plant is not None else constant_plant(options),
        landed=_flag(options, "landed", True),
        safety_switch_engaged=_flag(options, "safety", False),
        rc_calibrated=_flag(options, "rc_calibrated", True),
        frame_class=opt_int(options, "frame_class", 1, lo=0),
        frame_type=opt_int(options, "frame_type", 1, lo=0),
        init_delay_s=opt_float(options, "init_delay_s", 0.0, minimum=0.0),
        **_common(options),
    )


def register_mavlink_peers(
    plant_factory: PlantFactory = constant_plant, *, replace: bool = True
) -> None:
    def px4(options: Mapping[str, str]) -> BytePeer:
        return px4_from_options(options, plant_factory(options))

    def ardupilot(options: Mapping[str, str]) -> BytePeer:
        return ardupilot_from_options(options, plant_factory(options))

    register_peer("px4", px4, replace=replace)
    register_peer("ardupilot", ardupilot, replace=replace)
