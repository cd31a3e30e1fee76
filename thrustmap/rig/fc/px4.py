"""PX4 (v1.14+) over MAVLink: MAV_CMD_ACTUATOR_TEST, as a ``ThrottleOutput``.

- Command: ACTUATOR_TEST (310), value 0..1 to output function MOTOR``n+1`` for 0-based FC
  motor ``n``, NaN stops; PX4 caps the timeout at 3 s (the driver re-sends well inside it).
  A NaN stop never starts anything, so stops are always safe to send.
- **Throttle scale: ``SCALES["norm"]``, the 0..1 actuator-test value itself**, whatever the
  output protocol (PWM, Oneshot, DShot). The value passes through THR_MDL_FAC before the ESC:
  the driver records it and warns unless it is 0.
- Parameters: INT32 parameters arrive BYTEWISE (``COM_MOT_TEST_EN=1`` is the float 1.4e-45);
  the session decodes them by type and the vehicle's capability bits. COM_MOT_TEST_EN != 1 is
  refused at ``identify()`` with the fix named; PX4 DENIES a test while armed or with the
  safety on. Motor count: CA_ROTOR_COUNT.
- Output limits are per output in current PX4: PWM_MAIN_FUNC<ch> says which output drives
  MOTOR n (101 = Motor1 ...), and PWM_MAIN_MIN<ch>/MAX<ch>/DIS<ch> are read for exactly those
  outputs; older firmware's single PWM_MAIN_MIN/MAX/DIS are the fallback, asked for only when
  the per-output names are missing (a missing name is answered with PARAM_ERROR, so no time is
  wasted waiting for it). Stopped = an output below its running minimum (disarmed value or 0).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

from thrustmap.core.clock import Clock
from thrustmap.core.errors import ConfigError, SafetyError
from thrustmap.core.units import SCALES, ThrottleScale
from thrustmap.protocols.mavlink import codec as mav
from thrustmap.rig.fc.mavlink_output import MavlinkThrottleOutput

log = logging.getLogger(__name__)

PX4_PARAMS = ("COM_MOT_TEST_EN", "THR_MDL_FAC", "MC_BAT_SCALE_EN", "CA_ROTOR_COUNT")
PX4_MAX_OUTPUTS = 8  # PWM_MAIN_FUNC1..8
PX4_FUNCTION_MOTOR1 = 101  # PWM_MAIN_FUNCn value for Motor1 (Motor16 = 116)
LEGACY_PWM_PARAMS = ("PWM_MAIN_MIN", "PWM_MAIN_MAX", "PWM_MAIN_DIS")
DEFAULT_PWM_MIN_US = 1000.0


class Px4ThrottleOutput(MavlinkThrottleOutput):
    """PX4 v1.14+ over MAVLink with MAV_CMD_ACTUATOR_TEST; see the module docstring."""

    kind = "px4"
    telemetry_messages = (
        mav.MSG_SYS_STATUS,
        mav.MSG_BATTERY_STATUS,
        mav.MSG_ESC_STATUS,
        mav.MSG_SERVO_OUTPUT_RAW,
    )

    def __init__(self, link: Any, clock: Clock, **kwargs: Any) -> None:
        super().__init__(link, clock, **kwargs)
        if not 0 < self.test_timeout_s <= mav.PX4_ACTUATOR_TEST_MAX_TIMEOUT_S:
            raise ConfigError(
                f"PX4 actuator-test timeout must be in (0, 3] s, got {self.test_timeout_s:g}"
            )
        self.throttle_scale: ThrottleScale = SCALES["norm"]
        self.motor_outputs: dict[int, int] = {}  # 0-based motor -> 1-based output channel
        self.output_min_us: dict[int, float] = {}  # 1-based output channel -> PWM minimum

    def _read_firmware_params(self) -> dict[str, str]:
        params = self.read_params(PX4_PARAMS)
        details = {name: f"{value:g}" for name, value in params.items()}
        enabled = params.get("COM_MOT_TEST_EN")
        if enabled is not None and enabled != 1.0:
            raise SafetyError(
                f"PX4 has COM_MOT_TEST_EN={enabled:g}: actuator tests are disabled; set "
                "COM_MOT_TEST_EN=1 (and reboot) to run a stand test"
            )
        fac = params.get("THR_MDL_FAC")
        if fac is None:
            log.warning("could not read THR_MDL_FAC: the thrust-model factor in use is unknown")
            details["THR_MDL_FAC"] = "unknown"
        elif fac != 0.0:
            log.warning(
                "THR_MDL_FAC=%g shapes every actuator-test value before it reaches the ESC; "
                "set THR_MDL_FAC=0 for raw stand data, or keep this value with the data",
                fac,
            )
        return details

    def _param_motor_count(self) -> int:
        count = self.session.param("CA_ROTOR_COUNT")
        return int(count) if count is not None and 0 < count <= 16 else 0

    def _after_motor_count(self) -> dict[str, str]:
        return self._read_output_limits(self.motor_count or 4)

    def _read_output_limits(self, motors: int) -> dict[str, str]:
        """Which output drives each motor, and that output's PWM limits (see module)."""
        funcs = self.read_params([f"PWM_MAIN_FUNC{ch}" for ch in range(1, PX4_MAX_OUTPUTS + 1)])
        for name, value in funcs.items():
            motor = int(value) - PX4_FUNCTION_MOTOR1
            if 0 <= motor < 16:
                self.motor_outputs.setdefault(motor, int(name[len("PWM_MAIN_FUNC") :]))
        if not funcs:  # no function parameters: outputs in motor order
            self.motor_outputs = {m: m + 1 for m in range(min(motors, PX4_MAX_OUTPUTS))}
        channels = sorted(set(self.motor_outputs.values()))
        names = [f"PWM_MAIN_{k}{ch}" for ch in channels for k in ("MIN", "MAX", "DIS")]
        limits = self.read_params(names)
        legacy: dict[str, float] = {}
        if any(f"PWM_MAIN_MIN{ch}" not in limits for ch in channels):
            legacy = self.read_params(LEGACY_PWM_PARAMS)  # older PX4: one value for all
        for ch in channels:
            lo = limits.get(f"PWM_MAIN_MIN{ch}", legacy.get("PWM_MAIN_MIN"))
            if lo is not None:
                self.output_min_us[ch] = lo
        details: dict[str, str] = {}
        for name, value in {**limits, **legacy}.items():
            details[name] = f"{value:g}"
        if self.motor_outputs:
            details["motor_outputs"] = ", ".join(
                f"MOTOR{m + 1}->output {ch}" for m, ch in sorted(self.motor_outputs.items())
            )
        return details

    def motor_label(self, motor: int) -> str:
        ch = self.motor_outputs.get(motor)
        return f"motor {motor + 1}" + (f" (output {ch})" if ch is not None else "")

    def _send_throttle(self, values: dict[int, float]) -> None:
        for motor in sorted(self._current.keys() - values.keys()):  # no longer wanted: stop it
            self._require_accepted(
                mav.actuator_test_stop(motor + 1),
                f"ACTUATOR_TEST stop of {self.motor_label(motor)}",
            )
        for motor, value in sorted(values.items()):
            self._require_accepted(
                mav.actuator_test(motor + 1, value, timeout_s=self.test_timeout_s),
                f"ACTUATOR_TEST {self.motor_label(motor)} = {value:g}",
            )

    def _refusal_message(self, what: str, result: int, texts: Sequence[str]) -> str:
        text = super()._refusal_message(what, result, texts)
        if result == mav.MavResult.DENIED:
            hb = self.session.heartbeat.value if self.session.heartbeat is not None else None
            state = []
            if hb is not None and hb.armed:
                state.append("the vehicle reports ARMED")
            enabled = self.session.param("COM_MOT_TEST_EN")
            if enabled is not None and enabled != 1.0:
                state.append(f"COM_MOT_TEST_EN={enabled:g}")
            text += (
                ". PX4 denies actuator tests while armed, with the safety switch on, or when "
                "COM_MOT_TEST_EN != 1"
                + (f" (here: {', '.join(state)})" if state else " (check the safety switch)")
            )
        return text

    def _stop_commands(self) -> list[mav.CommandLong]:
        motors = self._motor_indices() or [0]
        return [mav.actuator_test_stop(m + 1) for m in motors if m < 16]

    def _outputs_stopped(self, outputs_us: Sequence[int], motors: Sequence[int]) -> bool:
        """Stopped = the motor's output below its running minimum: disarmed value, or 0."""
        for m in motors:
            ch = self.motor_outputs.get(m, m + 1)
            if ch - 1 >= len(outputs_us):
                continue
            if outputs_us[ch - 1] >= self.output_min_us.get(ch, DEFAULT_PWM_MIN_US):
                return False
        return True
