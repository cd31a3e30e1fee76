"""ONE bench session: open the devices, run a plan (or a spin), stop and verify on every way out.

``thrustmap sweep``, ``thrustmap spin`` and every script in ``scripts/`` go through here::

    rig = Rig(stand="sim://tyto-1585", throttle="sim://betaflight")
    with BenchSession(rig) as bench:   # its clock: choose_clock(rig.urls()); SIGTERM unwinds
        result = bench.sweep(plan, "run.csv", limits=Limits())
    sys.exit(exit_code(result.outcome, result.stop_verified))

What the session guarantees:

- SIGTERM (and SIGHUP) raise ``Terminated`` (a ``KeyboardInterrupt``) from the moment the first
  device is opened until the last one is closed, so every ``finally`` and context-manager exit
  runs (``rig.sigterm``).
- The throttle output is opened in ONE place (``BenchSession._open_output``) and closed in one
  place (its context exit: stop, verify, close — ``rig.interfaces.ThrottleOutput``), before the
  stand is closed. A per-session hook (a watchdog process, a recorder) belongs there.
- The clock rule lives here (``choose_clock``): simulated devices only -> ``SimClock`` (as fast as
  the computer goes, nothing sleeps for real); anything real -> the monotonic clock.
- One exit-code scheme for spin and sweep (``exit_code``, ``EXIT_CODES_HELP``).
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from types import TracebackType
from typing import Any

import thrustmap.rig.devices.opening as opening
import thrustmap.rig.devices.urls as devices_urls
from thrustmap.core.clock import Clock, MonotonicClock, SimClock
from thrustmap.core.errors import ConfigError
from thrustmap.rig.devices.opening import StandEscSpec
from thrustmap.rig.interfaces import Stand, ThrottleOutput
from thrustmap.rig.interlocks import SPIN_MAX_THROTTLE_PCT, Limits
from thrustmap.rig.plans import Plan
from thrustmap.rig.run_types import RunConfig, RunResult, Status
from thrustmap.rig.runner import record_sweep
from thrustmap.rig.sigterm import interrupts_deferred, terminate_as_exception
from thrustmap.rig.spin import SpinReport, SpinRequest, SpinResult, spin_on

log = logging.getLogger(__name__)

# --------------------------------------------------------------------------- exit codes

EXIT_DONE = 0  # completed, stop verified (or nothing was started)
EXIT_ABORTED = 1  # ended early by a limit, a silent device or a device error; stop verified
EXIT_REFUSED = 2  # refused or bad input: nothing was commanded
EXIT_STOP_NOT_VERIFIED = 3  # the motor stop could NOT be verified: disconnect the battery
EXIT_INTERRUPTED = 130  # Ctrl-C / SIGTERM; stop verified
EXIT_CODES_HELP = (
    "Exit codes: 0 done (stop verified); 1 aborted by a limit or a device failure (stop "
    "verified); 2 refused or bad input (nothing spun); 3 stop NOT verified (disconnect the "
    "battery); 130 interrupted by Ctrl-C/SIGTERM (stop verified)."
)


def exit_code(outcome: str, stop_verified: bool) -> int:
    """The process exit code for a run's ``outcome`` (completed | interrupted | aborted)."""
    if not stop_verified:
        return EXIT_STOP_NOT_VERIFIED
    if outcome == "completed":
        return EXIT_DONE
    if outcome == "interrupted":
        return EXIT_INTERRUPTED
    return EXIT_ABORTED


# --------------------------------------------------------------------------- clock


CLOCK_CHOICES = ("auto", "real", "sim")


def choose_clock(urls: Sequence[str], choice: str = "auto") -> Clock:
    """THE rule for simulated or real time. ``auto``: a ``SimClock`` when nothing real is
    behind any URL (``sim://``, ``replay://``, or those recorded), else the monotonic clock;
    ``real``: the monotonic clock (watch a simulation in real time); ``sim``: a ``SimClock``,
    refused when a device is real (its timeouts would be meaningless)."""
    choice = choice.lower()
    if choice not in CLOCK_CHOICES:
        raise ConfigError(f"clock must be one of {', '.join(CLOCK_CHOICES)}, got {choice!r}")
    real = [u for u in urls if not devices_urls.is_simulated(u)]
    if choice == "sim" and real:
        raise ConfigError(
            f"--clock sim needs simulated devices only; {', '.join(real)} is real "
            "(its timeouts and the run's duration would be meaningless)"
        )
    if choice == "sim" or (choice == "auto" and not real):
        return SimClock()
    return MonotonicClock()


# --------------------------------------------------------------------------- the rig


@dataclass(frozen=True)
class Rig:
    """Where the devices are and how to open them.

    ``throttle`` is the FC (or any throttle output) URL; None (or ``"stand"``) lets the stand
    drive the ESC itself. ``stand`` may be None for a spin without thrust readout; when the
    throttle URL is a stand (Tyto, line stand), its own stand is the session's stand."""

    stand: str | None = None
    throttle: str | None = None
    kind: str | None = None  # the throttle output's kind (msp, px4, ardupilot, ...); None: detect
    stand_kind: str | None = None
    baudrate: int | None = None
    calibration: str | None = None  # Tyto 1585 calibration JSON
    line_preset: str | None = None
    line_spec: str | None = None  # line stand spec JSON
    motor: int = 0  # 0-based; the motor a stand's own ESC output drives
    watchdog_log: str | None = None  # where an MSP output's motor-stop watchdog logs
    #: MAVLink 2 signing key (a ``protocols.mavlink.signing.SigningKey``; never in the repr)
    signing_key: Any = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.throttle == "stand":
            object.__setattr__(self, "throttle", None)
        if self.stand is None and self.throttle is None:
            raise ConfigError("give a stand URL, a throttle output URL, or both")

    def urls(self) -> list[str]:
        return [u for u in (self.stand, self.throttle) if u is not None]


def pairing_warnings(rig: Rig) -> list[str]:
    """What the operator must hear before anything spins (e.g. thrust from a simulated stand
    while a REAL motor turns: the recorded thrust would be noise)."""
    out: list[str] = []
    if rig.stand is not None and rig.throttle is not None:
        if devices_urls.is_simulated(rig.stand) and not devices_urls.is_simulated(rig.throttle):
            out.append(
                f"the stand {rig.stand} is simulated but the throttle output {rig.throttle} is "
                "real: a real motor will spin and the recorded thrust will be noise"
            )
        elif devices_urls.is_simulated(rig.throttle) and not devices_urls.is_simulated(rig.stand):
            out.append(
                f"the throttle output {rig.throttle} is simulated but the stand {rig.stand} is "
                "real: nothing will spin on the stand"
            )
    return out


_STAND_AS_THROTTLE = (
    "--throttle {url} is {kind}, not a flight controller: give the FC (MSP or MAVLink) that "
    "drives the motor on --stand, or omit --throttle to drive the ESC from the stand's own output"
)


class BenchSession:
    """The devices of one bench session, open between ``__enter__`` and ``__exit__`` (see
    module). ``output`` and ``stand`` are available inside the block."""

    def __init__(self, rig: Rig, clock: Clock | None = None) -> None:
        self.rig = rig
        #: the session's clock; by default THE rule (``choose_clock``): simulated time when
        #: nothing real is behind any of the rig's URLs, else the monotonic clock
        self.clock = clock if clock is not None else choose_clock(rig.urls())
        self._stack = contextlib.ExitStack()
        self._output: ThrottleOutput | None = None
        self._stand: Stand | None = None
        #: the stop commanded when the session closed: verified? (None: no output was open)
        self.stop_verified: bool | None = None
        #: why the stop could not be verified on this FC (it reports no motor values), if so
        self.stop_unverifiable: str | None = None

    @property
    def output(self) -> ThrottleOutput:
        if self._output is None:
            raise RuntimeError("the session is not open")
        return self._output

    @property
    def stand(self) -> Stand | None:
        return self._stand

    def __enter__(self) -> BenchSession:
        for warning in pairing_warnings(self.rig):
            log.info("%s", warning)  # the CLI and scripts show these before asking
        stack = self._stack
        # SIGTERM unwinds like Ctrl-C from here on, so every exit below stops the motors.
        stack.enter_context(terminate_as_exception())
        try:
            rig = self.rig
            if rig.stand is not None:
                self._stand = stack.enter_context(
                    opening.open_stand(
                        rig.stand,
                        self.clock,
                        kind=rig.stand_kind,
                        calibration=rig.calibration,
                        line_preset=rig.line_preset,
                        line_spec_file=rig.line_spec,
                    )
                )
            self._output = self._open_output()
            stack.callback(self._close_output, self._output)
            if self._stand is None and isinstance(self._output, opening.StandEscOutput):
                self._stand = self._output.stand
        except BaseException:
            stack.close()
            raise
        return self

    def _open_output(self) -> ThrottleOutput:
        """THE place a throttle output is opened (its context exit, run by the session's exit,
        stops, verifies and closes it; a hook that must live exactly as long as a commanded
        output goes here)."""
        rig = self.rig
        if rig.throttle is None:
            assert self._stand is not None
            return opening.stand_esc_output(self._stand, rig.motor)
        if rig.stand is not None and rig.throttle == rig.stand:
            raise ConfigError(_STAND_AS_THROTTLE.format(url=rig.throttle, kind="the stand"))
        output = opening.open_throttle_output(
            rig.throttle,
            self.clock,
            kind=rig.kind,
            baudrate=rig.baudrate if rig.stand is None else None,
            stand_esc=StandEscSpec(rig.motor, rig.calibration, rig.line_preset, rig.line_spec),
            watchdog_log=rig.watchdog_log,
            signing_key=rig.signing_key,
        )
        if rig.stand is not None and isinstance(output, opening.StandEscOutput):
            # a stand's own ESC output given as --throttle beside a measuring --stand: the roles
            # are checked here, after opening (which commands nothing) and before any command
            output.close()
            raise ConfigError(_STAND_AS_THROTTLE.format(url=rig.throttle, kind="a thrust stand"))
        return output

    def resolve_motor(self, text: str | int) -> tuple[int, str]:
        """The 0-based FC motor for ``--motor`` (a number, or an ArduPilot test-order letter)
        and its label ("motor 3 (test order A)"): the FC is identified first, since its frame
        says what a letter means."""
        from thrustmap.rig.fc.motor_numbers import motor_label, resolve_motor
        from thrustmap.rig.spin import check_motor_exists

        identity = self.output.identify()
        index = resolve_motor(self.output, text)
        check_motor_exists(index, identity)  # before the first motor command (rig.spin)
        return index, motor_label(self.output, index)

    def _close_output(self, output: ThrottleOutput) -> None:
        """THE place the throttle output is closed: stop, verify (a second Ctrl-C or SIGTERM
        cannot cut it short), then close; the verdict is kept in ``stop_verified``."""
        try:
            with interrupts_deferred():
                self.stop_verified = output.stop_and_verify()
                self.stop_unverifiable = getattr(output, "stop_unverifiable", None)
        finally:
            output.close()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self._stack.close()  # output first (stop, verify, close), then the stand, then signals
        self._output = None
        self._stand = None

    # -- what a session runs --------------------------------------------------------------------
    def sweep(
        self,
        plan: Plan,
        log_path: str,
        *,
        limits: Limits | None = None,
        config: RunConfig | None = None,
        monitor: Callable[[Status], None] | None = None,
        meta: dict[str, Any] | None = None,
    ) -> RunResult:
        """Run ``plan`` with the interlocks and record it as a Ds log."""
        if self._stand is None:
            raise ConfigError("a sweep needs a stand (--stand)")
        return record_sweep(
            plan,
            self.output,
            self._stand,
            log_path,
            self.clock,
            limits=limits,
            config=replace(
                config or RunConfig(), sidecar={**(config or RunConfig()).sidecar, **(meta or {})}
            ),
            monitor=monitor,
        )

    def spin(
        self,
        request: SpinRequest,
        *,
        max_throttle_pct: float = SPIN_MAX_THROTTLE_PCT,
        limits: Limits | None = None,
        on_report: Callable[[SpinReport], None] | None = None,
    ) -> SpinResult:
        """One short capped spin of one motor (``rig.spin``)."""
        return spin_on(
            self.output,
            self.clock,
            request,
            max_throttle_pct=max_throttle_pct,
            limits=limits,
            stand=self._stand,
            on_report=on_report,
        )
