"""ArduCopter over MAVLink: MAV_CMD_DO_MOTOR_TEST in PWM mode, as a ``ThrottleOutput``.

- Motors: 0-based FC motor ``n`` is ArduPilot's output function Motor``n+1``. DO_MOTOR_TEST
  takes a TEST-ORDER instance instead (A = 1, B = 2, ...); the frame's motor table
  (``thrustmap.protocols.mavlink.frames``, from FRAME_CLASS/FRAME_TYPE) translates: on a plus
  quad Motor3 is test A. ``instances=`` overrides the table (``instances[n]`` = the test order
  of motor n). ``motor_label`` names both. ESC telemetry and SERVO_OUTPUT_RAW are read at the
  motor's own output, assuming ArduCopter's default wiring (SERVOn_FUNCTION = Motor n).
- One motor at a time (a new command replaces the running test): two motors are refused.
- **Throttle scale: PWM µs** over MOT_PWM_MIN..MOT_PWM_MAX (both 0 means RC3_MIN/RC3_MAX, as
  ArduCopter does; else 1000..2000).
- A stop is itself a motor test (PWM 0, timeout 0): sent while NO test runs, ArduPilot accepts
  it and STARTS one (it arms for a moment). So the driver sends a stop only for a test it started
  that can still be running (its timeout has not passed and no "finished motor test" was seen
  since), and otherwise verifies the stop from SERVO_OUTPUT_RAW and a disarmed HEARTBEAT alone.
  ``identify()`` (``probe``) sends no motor command at all.
- Refusals come as COMMAND_ACK FAILED plus STATUSTEXT "Motor Test: ..." (right after boot:
  "Motor Test: Board initialising"); the text is in ``MotorTestRefused``. A refusal of our first
  command started nothing: no CRITICAL alarm follows it.
- While a test runs ArduPilot reports ARMED: that is expected; an ARMED HEARTBEAT counts only
  when no test of ours runs and it arrived after our last stop.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from typing import Any

from thrustmap.core.clock import Clock
from thrustmap.core.errors import ConfigError, SafetyError
from thrustmap.core.units import SCALES
from thrustmap.protocols.mavlink import codec as mav
from thrustmap.protocols.mavlink.frames import MotorOrder, motor_order, test_letter
from thrustmap.rig.fc.mavlink_output import MavlinkThrottleOutput

log = logging.getLogger(__name__)

ARDUPILOT_PARAMS = (
    "MOT_PWM_MIN",
    "MOT_PWM_MAX",
    "MOT_PWM_TYPE",
    "MOT_SPIN_ARM",
    "MOT_THST_EXPO",
    "FRAME_CLASS",
    "FRAME_TYPE",
)
MOT_PWM_TYPES = {
    0: "PWM",
    1: "ONESHOT",
    2: "ONESHOT125",
    3: "BRUSHED",
    4: "DSHOT150",
    5: "DSHOT300",
    6: "DSHOT600",
    7: "DSHOT1200",
    8: "PWMRANGE",
}
FINISHED_TEXT = "finished motor test"
#: after a test's timeout, how long it may still take the vehicle to end it
TIMEOUT_SLACK_S = 0.5


class ArduPilotThrottleOutput(MavlinkThrottleOutput):
    """ArduCopter over MAVLink with MAV_CMD_DO_MOTOR_TEST in PWM mode; see the module docstring."""

    kind = "ardupilot"
    telemetry_messages = (
        mav.MSG_SYS_STATUS,
        mav.MSG_BATTERY_STATUS,
        mav.MSG_ESC_TELEMETRY_1_TO_4,
        mav.MSG_SERVO_OUTPUT_RAW,
    )

    def __init__(
        self, link: Any, clock: Clock, *, instances: Sequence[int] | None = None, **kwargs: Any
    ) -> None:
        super().__init__(link, clock, **kwargs)
        if not 0 < self.test_timeout_s <= mav.ARDUPILOT_MOTOR_TEST_MAX_TIMEOUT_S:
            raise ConfigError(
                f"ArduPilot motor-test timeout must be in (0, 600] s, got {self.test_timeout_s:g}"
            )
        if instances is not None and (
            any(i < 1 for i in instances) or len(set(instances)) != len(instances)
        ):
            raise ConfigError(
                f"instances must be distinct test-order numbers >= 1, got {instances}"
            )
        self.order: MotorOrder | None = (
            MotorOrder("as given", tuple(instances)) if instances is not None else None
        )
        self.throttle_scale = SCALES["pwm"]
        self._pwm_type: int | None = None
        self._test_until_s: float | None = None  # our test may run until then
        self._test_seq = 0  # received-stream position of our last accepted command

    # -- numbering -----------------------------------------------------------------------------
    def _frame(self) -> tuple[int | None, int | None]:
        cls, typ = self.session.param("FRAME_CLASS"), self.session.param("FRAME_TYPE")
        return (None if cls is None else int(cls)), (None if typ is None else int(typ))

    def _order(self) -> MotorOrder:
        """The frame's table (kept once the parameters were read; until then not cached)."""
        if self.order is not None:
            return self.order
        order = motor_order(*self._frame(), self.motor_count or 4)
        if self._identity is not None:
            self.order = order
        return order

    def instance_for_motor(self, motor: int) -> int:
        """DO_MOTOR_TEST instance (test order) for 0-based FC motor ``motor``."""
        try:
            return self._order().instance_for(motor)
        except ConfigError as exc:
            raise SafetyError(str(exc)) from None

    def motor_for_test_order(self, instance: int) -> int:
        """0-based FC motor for a test-order number (``--motor A`` is 1)."""
        return self._order().motor_for(instance)

    def motor_label(self, motor: int) -> str:
        if self.order is None and self._identity is None:
            return f"motor {motor + 1}"  # the frame is not known yet
        try:
            letter = test_letter(self._order().instance_for(motor))
        except ConfigError:
            return f"motor {motor + 1}"
        return f"motor {motor + 1} (test order {letter})"

    # -- identify ------------------------------------------------------------------------------
    def _read_firmware_params(self) -> dict[str, str]:
        params = self.read_params(ARDUPILOT_PARAMS)
        details = {name: f"{value:g}" for name, value in params.items()}
        lo, hi = params.get("MOT_PWM_MIN", 0.0), params.get("MOT_PWM_MAX", 0.0)
        source = "MOT_PWM_MIN/MAX"
        if not (lo > 0 and hi > lo):
            rc = self.read_params(("RC3_MIN", "RC3_MAX"))
            lo, hi = rc.get("RC3_MIN", 0.0), rc.get("RC3_MAX", 0.0)
            source = "RC3_MIN/MAX"
            if not (lo > 0 and hi > lo):
                lo, hi, source = 1000.0, 2000.0, "default"
        lo_ok, hi_ok = mav.ARDUPILOT_MOTOR_TEST_PWM_RANGE_US
        if lo < lo_ok or hi > hi_ok:
            raise SafetyError(
                f"PWM range {lo:g}..{hi:g} µs ({source}) leaves ArduPilot's motor-test window "
                f"{lo_ok}..{hi_ok} µs: values outside it stop the test"
            )
        self.throttle_scale = SCALES["pwm"].with_range(lo, hi)
        details["pwm_range_source"] = source
        if "MOT_PWM_TYPE" in params:
            self._pwm_type = int(params["MOT_PWM_TYPE"])
        return details

    def _param_motor_count(self) -> int:
        if self.order is not None:
            return self.order.motor_count
        order = motor_order(*self._frame(), 0)
        return order.motor_count if order.known else 0

    def _after_motor_count(self) -> dict[str, str]:
        if self.order is None:
            self.order = motor_order(*self._frame(), self.motor_count or 4)
        order = self.order
        frame = order.frame
        if self._frame()[0] is None:  # never answered: say so, not "FRAME_CLASS None None"
            frame = "unknown (the FC did not answer FRAME_CLASS)"
        if not order.known:
            log.warning(
                "%s: assuming test order = motor number; check on the Motor Test page (or pass "
                "the test-order letter)",
                f"the frame is {frame}"
                if self._frame()[0] is None
                else f"frame {frame} is not in thrustmap's ArduPilot motor table",
            )
        return {"frame": frame, "test_order_known": str(order.known)}

    def motor_protocol(self) -> str:
        if self._pwm_type is None:
            return ""
        return MOT_PWM_TYPES.get(self._pwm_type, f"MOT_PWM_TYPE {self._pwm_type}")

    # -- motor test ----------------------------------------------------------------------------
    def _heartbeat_required(self) -> bool:
        return True  # ArduPilot disarms when the test ends: the HEARTBEAT confirms it

    def test_may_be_running(self) -> bool:
        """A test of ours was accepted, and neither its timeout has passed nor its end been seen
        ("finished motor test", then a disarmed HEARTBEAT). When unsure: running (a needless
        stop only arms the vehicle for a moment; a missing one leaves a motor turning)."""
        if self._test_until_s is None:
            return False
        s = self.session
        s.poll()
        finished = [
            t.seq for t in s.statustext if t.seq > self._test_seq and t.value == FINISHED_TEXT
        ]
        hb = s.heartbeat
        if finished and hb is not None and hb.seq > finished[-1] and not hb.value.armed:
            self._test_until_s = None  # ended, and the vehicle has disarmed since
            return False
        if self.clock.now_s() > self._test_until_s:
            self._test_until_s = None
            return False
        return True

    def _before_start(self, values: Mapping[int, float]) -> None:
        if len(values) > 1:
            raise SafetyError(
                "ArduPilot's DO_MOTOR_TEST runs one motor at a time (a new command replaces the "
                f"running test); got {len(values)} motors. Use one motor, or PX4/MSP for several"
            )
        if self._current:
            return  # our own test is running: ARMED is expected
        s = self.session
        s.poll()
        if self._stop_acked_s is not None:
            # HEARTBEATs from before our last stop still say ARMED: wait for a newer one.
            since = self._stop_acked_seq
            hb_ok = s.wait_until(
                lambda: s.heartbeat is not None and s.heartbeat.seq > since,
                s.heartbeat_timeout_s,
            )
            if not hb_ok:
                s.check_link()
        hb = s.heartbeat
        if hb is not None and hb.value.armed and not self.test_may_be_running():
            raise SafetyError(
                "the ArduPilot vehicle reports ARMED and no motor test of ours is running: "
                "disarm it (or wait for a previous test to time out) before a motor test"
            )

    def _send_throttle(self, values: dict[int, float]) -> None:
        ((motor, value),) = values.items()
        instance = self.instance_for_motor(motor)
        self._require_accepted(
            mav.motor_test(
                instance,
                round(value, 1),
                timeout_s=self.test_timeout_s,
                throttle_type=mav.MotorTestThrottleType.PWM,
            ),
            f"DO_MOTOR_TEST {self.motor_label(motor)} = {value:g} µs",
        )
        self._test_until_s = self.clock.now_s() + self.test_timeout_s + TIMEOUT_SLACK_S
        self._test_seq = self.session.rx_seq

    def _stop_commands(self) -> list[mav.CommandLong]:
        if not self.test_may_be_running():
            return []  # a stop now would START a motor test
        running = sorted(self._current) or sorted(self._commanded) or [0]
        return [mav.motor_test_stop(self.instance_for_motor(running[0]))]

    def _stop_is_idempotent_noop(self) -> bool:
        return not self._current and not self.test_may_be_running()

    def _after_stop_acked(self, *, refused: bool) -> None:
        if not refused:
            self._test_until_s = None  # our stop ended our test

    def _outputs_stopped(self, outputs_us: Sequence[int], motors: Sequence[int]) -> bool:
        """Stopped = at or below the PWM minimum (ArduPilot outputs MOT_PWM_MIN disarmed), or 0."""
        minimum = self.throttle_scale.lo
        return all(outputs_us[m] <= minimum for m in motors if m < len(outputs_us))
