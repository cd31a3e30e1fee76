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
from dataclasses import dataclass, field

from thrustmap.clock import Clock
from thrustmap.errors import ConfigError, SafetyError, ThrustmapError
from thrustmap.rig.interfaces import Stand, StandSample, Telemetry, ThrottleOutput
from thrustmap.rig.safety import interrupts_deferred, terminate_as_exception

log = logging.getLogger(__name__)

DEFAULT_MAX_THROTTLE_PCT = 20.0
MAX_SECONDS = 10.0


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


def check_spin(request: SpinRequest, max_throttle_pct: float = DEFAULT_MAX_THROTTLE_PCT) -> None:
    """Refuse a request outside the caps (nothing has been sent yet)."""
    if not 0.0 < max_throttle_pct <= 100.0:
        raise ConfigError(f"--max-throttle must be in (0, 100] %, got {max_throttle_pct:g}")
    pct = request.throttle_pct
    if not math.isfinite(pct) or pct < 0.0:
        raise ConfigError(f"throttle must be 0..100 %, got {pct:g}")
    if pct > max_throttle_pct:
        raise SafetyError(
            f"throttle {pct:g} % is above the {max_throttle_pct:g} % cap; raise it explicitly "
            f"with --max-throttle {math.ceil(pct):d} if you mean it"
        )
    if not 0.0 < request.seconds <= MAX_SECONDS:
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


def spin_on(
    output: ThrottleOutput,
    clock: Clock,
    request: SpinRequest,
    *,
    max_throttle_pct: float = DEFAULT_MAX_THROTTLE_PCT,
    stand: Stand | None = None,
    on_report: Callable[[SpinReport], None] | None = None,
) -> SpinResult:
    """``run_spin`` on an output its caller owns and closes (``rig.session.BenchSession``):
    the stop is commanded and verified here on every way out, and reported."""
    check_spin(request, max_throttle_pct)
    result = SpinResult()
    start_s = clock.now_s()
    try:
        _spin(output, clock, request, stand, on_report, result)
        result.status = "completed"
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM as Terminated
        result.status = "interrupted"
        result.reason = f"interrupted ({type(exc).__name__}{': ' + str(exc) if str(exc) else ''})"
        result.error = exc
        log.warning("spin %s: stopping", result.reason)
    except Exception as exc:
        result.status = "failed"
        result.reason = str(exc) if isinstance(exc, ThrustmapError) else repr(exc)
        result.error = exc
        log.error("spin failed: %s; stopping", result.reason)
    finally:
        result.duration_s = clock.now_s() - start_s
        # The owner's context exit stops and verifies again; this one is reported.
        with interrupts_deferred():
            result.stop_verified = output.stop_and_verify()
    return result


def _spin(
    output: ThrottleOutput,
    clock: Clock,
    request: SpinRequest,
    stand: Stand | None,
    on_report: Callable[[SpinReport], None] | None,
    result: SpinResult,
) -> None:
    identity = output.identify()
    if identity.motor_count and request.motor >= identity.motor_count:
        raise ConfigError(
            f"motor {request.motor + 1} does not exist: {identity.kind} reports "
            f"{identity.motor_count} motor(s)"
        )
    scale = output.throttle_scale
    t0 = clock.now_s()
    next_report_s = t0
    sent_pct: float | None = None
    sent_at_s = t0
    last_stand: StandSample | None = None
    while True:
        now = clock.now_s()
        elapsed = now - t0
        if elapsed >= request.seconds - 1e-9:  # (float ticks)
            break
        pct = request.throttle_pct
        if request.ramp_s > 0:
            pct = min(pct, pct * (elapsed + request.tick_s) / request.ramp_s)
        native = float(scale.from_pct(pct))
        if (
            sent_pct is None
            or abs(pct - sent_pct) > 1e-9
            or now - sent_at_s >= request.resend_s - 1e-9
        ):
            output.set_throttle({request.motor: native})
            sent_pct, sent_at_s = pct, now
            result.max_commanded_pct = max(result.max_commanded_pct, pct)
        else:
            output.keepalive()
        if stand is not None:
            samples = stand.read_samples()
            if samples:
                last_stand = samples[-1]
        if now >= next_report_s:
            telemetry: Telemetry | None = None
            try:
                telemetry = output.read_telemetry()
            except ThrustmapError as exc:
                log.warning("no telemetry: %s", exc)
            report = SpinReport(elapsed, pct, native, telemetry, last_stand)
            result.reports.append(report)
            if on_report is not None:
                on_report(report)
            next_report_s += request.report_period_s
        clock.sleep_s(request.tick_s)
