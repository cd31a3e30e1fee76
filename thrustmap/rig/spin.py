"""One short, capped spin of one motor (``thrustmap spin``): the smallest safe motor test.

``run_spin(output, clock, request)`` checks the request against the caps BEFORE anything is
sent (throttle at most ``max_throttle_pct`` — 20 % unless raised — and at most
``MAX_SECONDS``), ramps to the throttle, holds it, reports throttle/telemetry (and thrust when a
stand is given) every ``report_period_s``, then stops. The output is used as a context manager
and the stop is commanded and verified on every way out: the end of the spin, an exception in
a driver, Ctrl-C, and SIGTERM (turned into an exception by ``terminate_as_exception``).

``run_spin`` does not raise what happened during the spin: it returns a :class:`SpinResult`
whose ``status`` is ``completed``, ``interrupted`` (Ctrl-C/SIGTERM) or ``failed`` and whose
``error`` holds the exception, so the caller can report the stop verification first and then
re-raise with ``result.raise_error()``. Errors in the request itself (caps) raise at once.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

from thrustmap.core.clock import Clock
from thrustmap.core.errors import ConfigError, SafetyError, ThrustmapError
from thrustmap.rig.interfaces import Stand, StandSample, Telemetry, ThrottleOutput
from thrustmap.rig.interlocks import SPIN_MAX_SECONDS as MAX_SECONDS
from thrustmap.rig.interlocks import SPIN_MAX_THROTTLE_PCT as DEFAULT_MAX_THROTTLE_PCT
from thrustmap.rig.interlocks import Limits
from thrustmap.rig.plans import Plan
from thrustmap.rig.run_types import RunConfig, Status
from thrustmap.rig.runner import Runner
from thrustmap.rig.segments import Hold, Ramp, Segment
from thrustmap.rig.sigterm import interrupts_deferred, terminate_as_exception

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SpinRequest:
    motor: int  # 0-based
    throttle_pct: float  # percent of the output's throttle scale
    seconds: float
    ramp_s: float = 0.5
    tick_s: float = 0.05
    report_period_s: float = 1.0
    #: re-send the command at least this often: an FC that stopped answering (MSP acks every
    #: SET_MOTOR, MAVLink every command) ends the spin instead of going unnoticed
    resend_s: float = 0.5


@dataclass(frozen=True)
class SpinReport:
    """What the live readout shows once a second."""

    elapsed_s: float
    throttle_pct: float
    throttle_native: float
    telemetry: Telemetry | None
    stand: StandSample | None = None


@dataclass
class SpinResult:
    status: str = "not started"  # completed | interrupted | failed
    reason: str = ""
    stop_verified: bool = False
    duration_s: float = 0.0
    max_commanded_pct: float = 0.0
    reports: list[SpinReport] = field(default_factory=list)
    error: BaseException | None = None

    def raise_error(self) -> None:
        """Re-raise what ended the spin early (nothing when it completed)."""
        if self.error is not None:
            raise self.error


#: below this a throttle in % is a fraction typed as percent (0.5 meant as 50 %): no ESC spins
#: there (their spin-up is 3-10 %; Betaflight's idle is 5.5 % by default)
MIN_SPIN_PCT = 1.0


def check_spin(request: SpinRequest, max_throttle_pct: float = DEFAULT_MAX_THROTTLE_PCT) -> None:
    """Refuse a request outside the caps (nothing has been sent yet)."""
    if not 0.0 < max_throttle_pct <= 100.0:
        raise ConfigError(f"--max-throttle must be in (0, 100] %, got {max_throttle_pct:g}")
    pct = request.throttle_pct
    if not math.isfinite(pct) or pct < 0.0:
        raise ConfigError(f"throttle must be 0..100 %, got {pct:g}")
    if 0.0 < pct < MIN_SPIN_PCT:
        raise ConfigError(
            f"--throttle {pct:g} is in percent: {pct:g} % is below any ESC's spin-up, so "
            f"nothing would turn (did you mean {pct * 100:g} %?); give {MIN_SPIN_PCT:g} % or more"
        )
    if pct > max_throttle_pct:
        raise SafetyError(
            f"throttle {pct:g} % is above the {max_throttle_pct:g} % cap; raise it explicitly "
            f"with --max-throttle {math.ceil(pct):d} if you mean it"
        )
    if not request.seconds > 0:  # also NaN
        raise SafetyError(f"--seconds {request.seconds:g}: expected a positive duration")
    if not request.seconds <= MAX_SECONDS:
        raise SafetyError(
            f"a spin lasts at most {MAX_SECONDS:g} s (got {request.seconds:g} s); use "
            "`thrustmap sweep` for longer tests"
        )
    if request.motor < 0:
        raise ConfigError(f"motor index must be >= 0, got {request.motor}")
    if (
        request.ramp_s < 0
        or request.tick_s <= 0
        or request.report_period_s <= 0
        or request.resend_s <= 0
    ):
        raise ConfigError("ramp must be >= 0 s; tick, report and resend periods must be > 0 s")
    if request.ramp_s > request.seconds:
        reach = request.throttle_pct * request.seconds / request.ramp_s
        raise ConfigError(
            f"--ramp {request.ramp_s:g} s is longer than --seconds {request.seconds:g}: the motor "
            f"would reach only {reach:.3g} % of the {request.throttle_pct:g} % asked; lower --ramp"
        )


def check_motor_exists(motor: int, identity: Any) -> None:
    """Refuse a 0-based ``motor`` the FC does not have (its identity's ``motor_count``; 0 or
    None: unknown, not refused). Called when the motor is resolved, before any command."""
    count = getattr(identity, "motor_count", None)
    if count and motor >= count:
        raise ConfigError(
            f"--motor {motor + 1}: motor {motor + 1} does not exist: "
            f"{getattr(identity, 'kind', 'the FC')} reports {count} motor(s); nothing spun"
        )


def run_spin(
    output: ThrottleOutput,
    clock: Clock,
    request: SpinRequest,
    *,
    max_throttle_pct: float = DEFAULT_MAX_THROTTLE_PCT,
    stand: Stand | None = None,
    on_report: Callable[[SpinReport], None] | None = None,
) -> SpinResult:
    """Spin one motor once (see module). ``output`` is entered and closed here."""
    check_spin(request, max_throttle_pct)
    with terminate_as_exception(), output:
        return spin_on(
            output,
            clock,
            request,
            max_throttle_pct=max_throttle_pct,
            stand=stand,
            on_report=on_report,
        )


def spin_plan(request: SpinRequest) -> Plan:
    """The spin as a plan: a ramp from 0 to the throttle over ``ramp_s``, then a hold."""
    pct, ramp_s = request.throttle_pct, min(request.ramp_s, request.seconds)
    segments: list[Segment] = []
    if ramp_s > 0:
        end = pct * ramp_s / request.ramp_s  # (cut short when the spin is shorter than the ramp)
        segments.append(Ramp(0.0, end, ramp_s, label="ramp"))
    if request.seconds - ramp_s > 1e-9:
        segments.append(Hold(pct, request.seconds - ramp_s, label="hold"))
    return Plan("spin", tuple(segments), {"motor": request.motor + 1, "throttle_pct": pct})


def spin_on(
    output: ThrottleOutput,
    clock: Clock,
    request: SpinRequest,
    *,
    max_throttle_pct: float = DEFAULT_MAX_THROTTLE_PCT,
    stand: Stand | None = None,
    on_report: Callable[[SpinReport], None] | None = None,
    limits: Limits | None = None,
) -> SpinResult:
    """``run_spin`` on an output its caller owns and closes (``rig.session.BenchSession``).

    The spin is a plan run by the sweep's runner (``rig.runner.Runner``: the same control loop,
    link watchdog, interlocks and verified stop), without recording and without taring; a stand,
    when given, adds thrust to the reports and its interlocks."""
    check_spin(request, max_throttle_pct)
    result = SpinResult()
    try:
        check_motor_exists(request.motor, output.identify())
    except Exception as exc:
        result.status, result.error = "failed", exc
        result.reason = str(exc) if isinstance(exc, ThrustmapError) else repr(exc)
        with interrupts_deferred():
            result.stop_verified = output.stop_and_verify()
        return result
    plan = spin_plan(request)
    limits = replace(
        limits or Limits(),
        max_throttle_pct=max_throttle_pct,
        max_slew_pct_s=max(Limits().max_slew_pct_s, plan.max_ramp_slew_pct_s()),
    )
    config = RunConfig(
        motor=request.motor,
        tick_s=request.tick_s,
        keepalive_s=request.resend_s,
        tare=False,
        # nothing to confirm before ONE capped spin: a stop sent to an idle ArduPilot STARTS a
        # motor test (and its verification waits for the acknowledgement)
        check_at_rest=False,
    )
    reporter = _Reporter(request, result, on_report)
    runner = Runner(
        plan, output, stand, None, clock, limits=limits, config=config, monitor=reporter
    )
    try:
        run = runner.run()
    except Exception as exc:  # a driver failed: the runner has stopped the motor first
        result.status, result.error = "failed", exc
        result.reason = str(exc) if isinstance(exc, ThrustmapError) else repr(exc)
        result.stop_verified = bool(runner.stop_verified)
        log.error("spin failed: %s", result.reason)
        return result
    result.duration_s = run.duration_s
    result.stop_verified = run.stop_verified
    result.reason = run.reason
    if run.outcome == "completed":
        result.status = "completed"
    elif run.outcome == "interrupted":
        result.status = "interrupted"
        result.error = KeyboardInterrupt(run.reason)
    else:
        result.status = "failed"
        result.error = SafetyError(run.reason)
    return result


class _Reporter:
    """Turns the runner's per-tick status into a ``SpinReport`` every ``report_period_s``."""

    def __init__(
        self,
        request: SpinRequest,
        result: SpinResult,
        on_report: Callable[[SpinReport], None] | None,
    ) -> None:
        self.request = request
        self.result = result
        self.on_report = on_report
        self.next_report_s = 0.0

    def __call__(self, st: Status) -> None:
        if st.phase != "plan":
            return
        self.result.max_commanded_pct = max(self.result.max_commanded_pct, st.throttle_pct)
        if st.elapsed_s + 1e-9 < self.next_report_s:
            return
        if st.elapsed_s >= self.request.seconds - self.request.tick_s / 2:
            return  # the last tick of the plan (float time): the spin is over
        report = SpinReport(
            st.elapsed_s, st.throttle_pct, st.throttle_native, st.telemetry, st.sample
        )
        self.result.reports.append(report)
        if self.on_report is not None:
            self.on_report(report)
        self.next_report_s += self.request.report_period_s
