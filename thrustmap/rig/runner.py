"""Execute a sweep plan on a stand and a throttle output, with interlocks, and record Ds.

Every run ends with a verified stop, whatever happens: the plan finishing, a tripped limit,
an exception inside the plan or a driver, Ctrl-C, SIGTERM, the stand going quiet (watchdog), or
the throttle output's link failing, and across voltage before a pack change (the stop is
verified before the user is asked, and nothing is commanded until the new pack's voltage has
been checked). The Ds log is flushed sample by sample and its sidecar
records the outcome, so an aborted run still loads in ``thrustmap fit``.

One monotonic clock (injected) timestamps everything; with a ``SimClock`` a test runs a
minute-long sweep in milliseconds and never sleeps for real.

What a run is set up with, reports and returns (``RunConfig``, ``Status``, ``RunResult``) is in
``rig.run_types``. The ``Runner`` itself stays one class on purpose: every
way out of a run (and every stop it must verify) is in one place.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any, NoReturn

import numpy as np

from thrustmap.core.clock import Clock
from thrustmap.core.errors import SafetyError
from thrustmap.core.stand_recording import DsWriter
from thrustmap.rig.adaptive_plan import SettledPoint
from thrustmap.rig.interfaces import DeviceAbort, Stand, StandSample, Telemetry, ThrottleOutput
from thrustmap.rig.interlocks import (
    Limits,
    Reading,
    ThrustResponse,
    Trip,
    check,
    check_plan,
    margins,
)
from thrustmap.rig.plans import Plan
from thrustmap.rig.run_types import RunConfig, RunResult, Status
from thrustmap.rig.segments import (
    PACK_MOVE_MIN_REL,
    Discharge,
    Hold,
    PackChange,
    Ramp,
    RunSegment,
    Segment,
)
from thrustmap.rig.settle import RestDetector, SettleDetector
from thrustmap.rig.sigterm import Terminated, interrupts_deferred, terminate_as_exception

log = logging.getLogger(__name__)


class Aborted(Exception):
    def __init__(self, reason: str, trip: Trip | None = None) -> None:
        super().__init__(reason)
        self.reason = reason
        self.trip = trip


class Runner:
    def __init__(
        self,
        plan: Plan,
        output: ThrottleOutput,
        stand: Stand | None,
        writer: DsWriter | None,
        clock: Clock,
        *,
        limits: Limits | None = None,
        config: RunConfig | None = None,
        monitor: Callable[[Status], None] | None = None,
    ) -> None:
        """``stand`` None: a run on the throttle output alone (``thrustmap spin``), its readings
        (and interlocks) from the output's telemetry; ``writer`` None: nothing recorded."""
        self.plan = plan
        self.output = output
        self.stand = stand
        self.writer = writer
        self.clock = clock
        self.limits = limits or Limits()
        self.cfg = config or RunConfig()
        self.monitor = monitor
        self.scale = output.throttle_scale
        self._cmd_pct = 0.0
        self._sent_pct: float | None = None
        self._sent_at = -1e9
        self._last_sample_at = 0.0
        self._last_link_ok = 0.0
        self._telemetry: Telemetry | None = None
        self._telemetry_at = -1e9
        self._reading = Reading()
        self._abort_at: float | None = None
        self._t0 = 0.0
        self._segment_index = 0
        self._label = ""
        self._target_pct_now = 0.0
        self._start = 0.0
        self._phase = "at-rest"
        self._last_sample: StandSample | None = None
        self._failing_since: float | None = None  # when throttle commands started failing
        #: thrust must follow the confirmed command (interlock ``min_thrust_by_pct``)
        self._response = ThrustResponse(self.limits, plan.max_throttle_pct)
        #: the verdict of the final stop (also when ``run`` re-raises a driver's exception)
        self.stop_verified: bool | None = None
        # what each hold measured, for an adaptive plan (``plans.SettledPoint``)
        self._collect = False
        self._held: list[tuple[float, float | None, float | None]] = []
        self._energy_j = 0.0
        self._energy_t: float | None = None

    # -- public ---------------------------------------------------------------------------------
    def run(self) -> RunResult:
        check_plan(self.plan, self.limits)  # refuse before anything spins
        status, reason, trip, interrupted = "aborted", "", None, False
        self._t0 = self._start = self.clock.now_s()
        with terminate_as_exception():
            try:
                try:
                    self._preflight()
                    for i, seg in enumerate(self.plan.run_segments()):
                        self._segment_index = i
                        self._held = []
                        if isinstance(seg, PackChange):
                            self._change_pack(seg)
                            continue
                        if isinstance(seg, Discharge):
                            self._run_discharge(seg)
                        else:
                            self._run_segment(seg)
                        self._observe(seg)
                    status, reason = "completed", ""
                    if self.plan.adaptive is not None:
                        reason = self.plan.adaptive.stop_reason
                except Aborted as exc:
                    reason, trip = exc.reason, exc.trip
                except DeviceAbort as exc:  # the device stopped the run (a core's cutoff)
                    reason = str(exc)
                except Terminated as exc:
                    reason, interrupted = f"terminated ({exc})", True
                except KeyboardInterrupt:
                    reason, interrupted = "interrupted (Ctrl-C)", True
                except Exception as exc:  # a driver or plan failure: stop first, then report
                    reason = f"{type(exc).__name__}: {exc}"
                    raise
            finally:
                if self._abort_at is None:
                    self._abort_at = self.clock.now_s()
                stop_at = self.clock.now_s()
                with interrupts_deferred():
                    verified = self.stop_verified = self._stop_until_verified()
                    latency = stop_at - self._abort_at
                    if status != "completed":
                        log.warning(
                            "run aborted: %s; motors %s",
                            reason,
                            "stopped (verified)" if verified else "STOP NOT VERIFIED",
                        )
                    self._drain_after_stop()
                if self.writer is not None:
                    self.writer.finish(
                        status,
                        reason,
                        extra={
                            "stop_verified": verified,
                            "stop_unverifiable": getattr(self.output, "stop_unverifiable", None),
                            "stop_latency_s": latency,
                            "trip": None if trip is None else trip.__dict__,
                            **self._adaptive_meta(),
                        },
                    )
        return RunResult(
            status,
            reason,
            0 if self.writer is None else self.writer.rows,
            self.clock.now_s() - self._t0,
            verified,
            latency,
            trip,
            "" if self.writer is None else str(self.writer.path),
            interrupted,
            self._t0 - self._start,
        )

    # -- internals -------------------------------------------------------------------------------
    def _adaptive_meta(self) -> dict[str, Any]:
        if self.plan.adaptive is None:
            return {}
        return {"adaptive": self.plan.adaptive.summary()}

    def _observe(self, seg: RunSegment) -> None:
        """An adaptive plan hears what the hold measured; its record goes into the sidecar at
        once, so a run that is killed keeps why each point was chosen."""
        driver = self.plan.adaptive
        if driver is None or not isinstance(seg, Hold | Discharge):
            return
        held = self._held
        volts = [v for _, v, _ in held if v is not None]
        amps = [a for _, _, a in held if a is not None]
        driver.observe(
            SettledPoint(
                throttle_pct=seg.throttle_pct,
                thrust_n=float(np.mean([t for t, _, _ in held])) if held else float("nan"),
                voltage_v=float(np.mean(volts)) if volts else None,
                current_a=float(np.mean(amps)) if amps else None,
                samples=len(held),
                settled=self._label.endswith("-settled"),
                elapsed_s=self.clock.now_s() - self._t0,
                energy_wh=self._energy_j / 3600.0,
                label=seg.label,
            ),
            {
                "max_thrust_n": self.limits.max_thrust_n,
                "max_current_a": self.limits.max_current_a,
                **(
                    {"min_voltage_v": self.limits.min_voltage_v}
                    if self.limits.min_voltage_v is not None
                    else {}
                ),
            },
        )
        if self.writer is not None:
            self.writer.note(self._adaptive_meta())
        self._report(self.clock.now_s())

    def _run_discharge(self, seg: Discharge) -> None:
        """Hold ``seg.throttle_pct`` until the voltage under that load, averaged over
        ``seg.record_s``, has fallen to ``seg.until_v`` (or ``seg.max_s``). Every sample goes
        through ``_record``: the interlocks (current, temperature, minimum voltage) stay on."""
        start = self.clock.now_s()
        self._label = seg.label
        window: list[tuple[float, float]] = []  # (time, voltage) over the last record_s
        recent: list[tuple[float, float, float | None, float | None]] = []
        while True:
            now = self.clock.now_s()
            if now - start >= seg.max_s:
                log.info("discharge did not reach %.2f V within %.0f s", seg.until_v, seg.max_s)
                break
            self._command(seg.throttle_pct, now)
            samples = self._poll(now)
            reading = self._reading
            if samples and reading.voltage_v is not None:
                window.append((now, reading.voltage_v))
                recent.extend(
                    (now, s.thrust_n, reading.voltage_v, reading.current_a) for s in samples
                )
            window = [w for w in window if w[0] >= now - seg.record_s]
            recent = [r for r in recent if r[0] >= now - seg.record_s]
            slewing = abs(self._cmd_pct - seg.throttle_pct) > 1e-9
            if (
                not slewing
                and window
                and now - window[0][0] >= 0.9 * seg.record_s
                and sum(v for _, v in window) / len(window) <= seg.until_v
            ):
                break
            self._report(now)
            self.clock.sleep_s(self.cfg.tick_s)
        self._held = [(t, v, a) for _, t, v, a in recent]

    def _change_pack(self, seg: PackChange) -> None:
        """Across voltage: stop the motor and verify the stop (the run's stop contract), read
        the voltage at rest, ask for the other pack through the plan, check that the voltage
        at rest moved toward ``seg.wanted_v``, then wait for rest and tare again. Nothing is
        commanded from the stop until the plan's next level."""
        driver = self.plan.adaptive
        assert driver is not None
        self._label = seg.label
        if not self._stop_until_verified():
            self._abort("pack change: the motor stop was NOT verified; no pack is asked for")
        self._cmd_pct, self._sent_pct = 0.0, None  # nothing is sent until the next level
        if self.stand is not None:
            self._wait_at_rest()  # the rotor still before anyone reaches for the pack
        before = self._rest_voltage()
        log.info("pack change: %s", seg.message)
        connected = driver.connect_pack is not None and driver.connect_pack(seg)
        now = self.clock.now_s()
        self._last_link_ok = self._last_sample_at = now  # the question held the loop
        self._energy_t = None  # nothing drawn while the pack was out
        if not connected:
            driver.pack_changed(seg.wanted_v, before, None)
            driver.stop_reason = (
                f"across voltage: no other pack was connected (wanted about {seg.wanted_v:.2f} V)"
            )
            return
        if self.stand is not None:  # what the stand read while the pack was out: kept, not
            self._write_rest(self.stand.read_samples(), "pack-change")  # the new pack's voltage
        after = self._rest_voltage()
        driver.pack_changed(seg.wanted_v, before, after)
        if before is None or after is None:
            self._abort("pack change: no voltage reading to check that the pack changed")
        moved = after - before
        if abs(moved) < PACK_MOVE_MIN_REL * before or (seg.wanted_v - before) * moved < 0:
            self._abort(
                f"pack change: the voltage at rest went {before:.2f} -> {after:.2f} V, not "
                f"toward {seg.wanted_v:.2f} V by {100 * PACK_MOVE_MIN_REL:.0f} %: was the pack "
                "changed? nothing spins on it"
            )
        if self.cfg.tare and self.stand is not None:
            self._wait_at_rest()
            self.stand.tare(service=lambda: self._service_link(self.clock.now_s()))
        self._last_sample_at = self.clock.now_s()

    def _rest_voltage(self, seconds: float = 1.0) -> float | None:
        """Mean battery voltage over ``seconds`` with the motor stopped (stand, else the
        output's telemetry); the samples are kept in the log (phase ``pack-change``)."""
        start = self.clock.now_s()
        volts: list[float] = []
        while self.clock.now_s() - start < seconds:
            now = self.clock.now_s()
            self._service_link(now)
            samples = [] if self.stand is None else self.stand.read_samples()
            if samples:
                self._last_sample_at = now
            self._write_rest(samples, "pack-change")
            volts.extend(s.voltage_v for s in samples if s.voltage_v is not None)
            if not samples and self._telemetry is not None and self._telemetry.voltage_v:
                volts.append(self._telemetry.voltage_v)
            self._report(now)
            self.clock.sleep_s(self.cfg.tick_s)
        return sum(volts) / len(volts) if volts else None

    def _stop_until_verified(self) -> bool:
        """Stop and verify; on a lost link keep re-sending for ``stop_retry_s`` (Betaflight keeps
        the last motor value forever, so giving up after one try is not an option)."""
        deadline = self.clock.now_s() + self.cfg.stop_retry_s
        while True:
            # one CRITICAL at the end of the loop, not one per failed attempt
            if self.output.stop_and_verify(attempts=1, alarm=False):
                return True
            if getattr(self.output, "stop_unverifiable", None):
                return False  # acknowledged, but this FC cannot confirm a stop: no retry loop
            if self.clock.now_s() >= deadline:
                log.critical(
                    "motor stop NOT verified after %.0f s: disconnect the battery",
                    self.cfg.stop_retry_s,
                )
                return False
            self.clock.sleep_s(0.1)

    def _motors(self) -> list[int]:
        if self.cfg.rotors_on_esc > 1:
            return list(range(self.cfg.rotors_on_esc))
        return [self.cfg.motor]

    def _abort(self, reason: str, trip: Trip | None = None) -> NoReturn:
        self._abort_at = self.clock.now_s()
        log.info("aborting: %s", reason)  # when it was decided (-v); the verdict follows the stop
        raise Aborted(reason, trip)

    def _preflight(self) -> None:
        """Before the plan: identify, confirm the motors at rest, wait for the rotor to be still
        and tare. Every device's link is serviced all along (``_service_link``): FC telemetry and
        heartbeats are read, a silent FC aborts the run, and Ctrl-C stops at once."""
        self._phase = "at-rest"
        self._last_link_ok = self._last_sample_at = self.clock.now_s()
        ident = self.output.identify()
        log.info(
            "throttle output: %s %s (%s)", ident.kind, ident.firmware_version, ident.motor_protocol
        )
        # Verify first; stop only when needed (a stop sent to an idle ArduPilot STARTS a test).
        if self.cfg.check_at_rest and not self.output.verify_stopped():
            self.output.stop()
            if not self.output.verify_stopped():
                blind = getattr(self.output, "stop_unverifiable", None)
                if not blind:
                    raise SafetyError("motors are not at rest before the run; refusing to start")
                log.warning("cannot confirm the motors are at rest: %s", blind)
        self._last_link_ok = self.clock.now_s()
        for device in (self.stand, self.output):  # limits the device enforces itself too
            install = getattr(device, "install_limits", None)
            if callable(install):
                install(self.limits)
        if self.cfg.tare and self.stand is not None:
            self._wait_at_rest()
            self._phase = "tare"
            self._report(self.clock.now_s())
            self.stand.tare(service=lambda: self._service_link(self.clock.now_s()))
            self._response.start(tared=True)
        if self.stand is not None and self._response.enabled and self._response.band_n is None:
            log.info("thrust-response interlock off: no at-rest readings to measure noise with")
        now = self.clock.now_s()
        self._last_sample_at = now
        self._service_link(now)
        self._phase = "plan"
        self._t0 = now  # the plan's progress and ETA start here

    def _service_link(self, now: float) -> None:
        """Read the throttle output's link (telemetry; heartbeats for MAVLink) at the telemetry
        period and abort when it has been silent longer than ``link_timeout_s``. Used in every
        phase: before the plan nothing else would read the FC, and its stream would pile up."""
        if now - self._telemetry_at >= self.cfg.telemetry_period_s:
            self._telemetry_at = now
            try:
                self._telemetry = self.output.read_telemetry()
                self._last_link_ok = self.clock.now_s()
            except SafetyError:
                raise
            except Exception as exc:
                self._link_failure(f"telemetry failed: {exc}")
        if self.clock.now_s() - self._last_link_ok > self.limits.link_timeout_s:
            self._abort(
                f"lost link to the throttle output: no answer for "
                f"{self.clock.now_s() - self._last_link_ok:.2f} s"
            )

    def _wait_at_rest(self) -> None:
        """Tare only once the rotor has stopped: thrust steady (and rpm ~0 where measured) for
        ``spin_down_s``. A previous run's coasting rotor would otherwise become the zero."""
        assert self.stand is not None
        start = self.clock.now_s()
        detector = RestDetector(self.cfg.spin_down_s)
        while self.clock.now_s() - start < self.cfg.spin_down_max_s:
            now = self.clock.now_s()
            self._service_link(now)
            samples = self.stand.read_samples()
            for sample in samples:
                self._response.rest_sample(sample.time_s, sample.thrust_n)
            if detector.update(now, samples) and now - start >= (self.cfg.spin_down_s):
                return
            self._report(now)
            self.clock.sleep_s(self.cfg.tick_s)
        raise SafetyError(
            f"the rotor did not come to rest within {self.cfg.spin_down_max_s:.0f} s before "
            f"taring: {detector.why_not}"
        )

    def _target_pct(self, seg: Segment, t_in: float) -> float:
        if isinstance(seg, Ramp):
            f = min(max(t_in / seg.duration_s, 0.0), 1.0)
            return seg.start_pct + f * (seg.end_pct - seg.start_pct)
        return seg.throttle_pct

    def _run_segment(self, seg: Segment) -> None:
        start = self.clock.now_s()
        self._label = seg.label
        length = seg.duration_s if isinstance(seg, Ramp) else seg.dwell_s
        settle = isinstance(seg, Hold) and seg.settle
        detector = SettleDetector(
            self.cfg.settle_window_s, self.cfg.settle_band_n, self.cfg.settle_rel
        )
        settled_at: float | None = None
        record_s = seg.record_s if isinstance(seg, Hold) else 0.0
        while True:
            now = self.clock.now_s()
            t_in = now - start
            # the part of a hold that describes it: after settling, else its last record_s
            self._collect = (settled_at is not None) if settle else t_in >= length - record_s
            if t_in >= length:
                if settle:
                    log.info("hold %.1f %% did not settle within %.1f s", self._cmd_pct, length)
                return
            if settle and settled_at is not None and now - settled_at >= seg.record_s:  # type: ignore[union-attr]
                return
            self._command(self._target_pct(seg, t_in), now)
            samples = self._poll(now)
            if settle and settled_at is None:
                # still slewing toward the level: not settled whatever thrust does
                slewing = abs(self._cmd_pct - self._target_pct_now) > 1e-9
                if detector.update(now, samples) and not slewing:
                    settled_at = now
                    self._label = f"{seg.label}-settled"
            self._report(now)
            self.clock.sleep_s(self.cfg.tick_s)

    def _command(self, target_pct: float, now: float) -> None:
        self._target_pct_now = target_pct
        # Slew-rate limit (steps become short ramps at the configured rate).
        max_step = self.limits.max_slew_pct_s * self.cfg.tick_s
        delta = float(np.clip(target_pct - self._cmd_pct, -max_step, max_step))
        # never above the interlock's ceiling nor above what the plan was asked to reach
        ceiling_pct = self.limits.max_throttle_pct
        if self.plan.ceiling_pct is not None:
            ceiling_pct = min(ceiling_pct, self.plan.ceiling_pct)
        self._cmd_pct = min(self._cmd_pct + delta, ceiling_pct)
        if self._sent_pct is None and self._cmd_pct <= 0.0:
            return  # nothing commanded yet and nothing to command: the motors are stopped
        changed = self._sent_pct is None or abs(self._cmd_pct - self._sent_pct) > 1e-9
        if changed or now - self._sent_at >= self.cfg.keepalive_s:
            native = float(self.scale.from_pct(self._cmd_pct))
            try:
                if changed:
                    self.output.set_throttle({m: native for m in self._motors()})
                    self._last_link_ok = self.clock.now_s()
                else:
                    self.output.keepalive()  # a no-op for MSP: proves nothing about the link
            except SafetyError:
                raise
            except Exception as exc:
                # Not sent: retried next tick. Commands that keep failing end the run even
                # while telemetry still answers (a run whose commands do not go out is a failure).
                if self._failing_since is None:
                    self._failing_since = now
                if now - self._failing_since >= self.limits.link_timeout_s:
                    self._abort(f"lost link to the throttle output: commands failing: {exc}")
                self._link_failure(f"throttle output failed: {exc}")
                return
            self._failing_since = None
            self._sent_pct = self._cmd_pct
            self._sent_at = now

    def _link_failure(self, reason: str) -> None:
        if self.clock.now_s() - self._last_link_ok >= self.limits.link_timeout_s:
            self._abort(f"lost link to the throttle output: {reason}")
        log.warning("%s (retrying)", reason)

    def _poll(self, now: float) -> list[StandSample]:
        if self.stand is None:
            before = self._telemetry
            self._service_link(now)
            if self._telemetry is not before:
                self._check_telemetry()
            return []
        try:
            samples = self.stand.read_samples()
        except SafetyError:
            raise
        except Exception as exc:
            self._abort(f"lost link to the stand: {exc}")
        if samples:
            self._last_sample_at = self.clock.now_s()
        elif now - self._last_sample_at > self.limits.stale_data_s:
            self._abort(
                f"stale stand data: no sample for {now - self._last_sample_at:.2f} s "
                f"(limit {self.limits.stale_data_s:.2f} s)"
            )
        self._service_link(now)
        for s in samples:
            self._record(s)
        return samples

    def _check_telemetry(self) -> None:
        """Without a stand: the interlocks on what the output itself reports."""
        tel = self._telemetry
        if tel is None:
            return
        rpm = tel.rpm[self.cfg.motor] if tel.rpm and self.cfg.motor < len(tel.rpm) else None
        self._reading = Reading(
            current_a=tel.current_a,
            voltage_v=tel.voltage_v,
            rpm=rpm,
            temperature_c=max(tel.temperature_c) if tel.temperature_c else None,
        )
        trip = check(self.limits, self._reading)
        if trip is not None:
            self._abort(f"limit tripped: {trip.message}", trip)

    def _record(self, s: StandSample) -> None:
        tel = self._telemetry
        rpm = s.rpm
        if rpm is None and tel is not None and tel.rpm:
            rpm = tel.rpm[self.cfg.motor] if self.cfg.motor < len(tel.rpm) else None
        temp = s.temperature_c
        if temp is None and tel is not None and tel.temperature_c:
            temp = max(tel.temperature_c)
        reading = Reading(
            thrust_n=s.thrust_n,
            current_a=s.current_a if s.current_a is not None else (tel.current_a if tel else None),
            voltage_v=s.voltage_v if s.voltage_v is not None else (tel.voltage_v if tel else None),
            rpm=rpm,
            temperature_c=temp,
            vibration_g=s.vibration_g,
        )
        self._reading = reading
        self._last_sample = s
        if reading.voltage_v is not None and reading.current_a is not None:
            if self._energy_t is not None and s.time_s > self._energy_t:
                self._energy_j += (
                    reading.voltage_v * reading.current_a * (s.time_s - self._energy_t)
                )
            self._energy_t = s.time_s
        if self._collect:
            self._held.append((s.thrust_n, reading.voltage_v, reading.current_a))
        throttle = (
            s.throttle_native
            if s.throttle_native is not None
            else float(self.scale.from_pct(self._cmd_pct))
        )
        if self.writer is not None:
            self._write(s, throttle, reading)
        trip = check(self.limits, reading) or self._response.update(
            self.clock.now_s(), self._sent_pct or 0.0, reading.thrust_n, reading.rpm
        )
        if trip is not None:
            self._abort(f"limit tripped: {trip.message}", trip)

    def _write(self, s: StandSample, throttle: float, reading: Reading) -> None:
        assert self.writer is not None
        self.writer.write(
            s.time_s,
            throttle,
            {
                "thrust_n": s.thrust_n,
                "voltage_v": reading.voltage_v,
                "current_a": reading.current_a,
                "rpm": reading.rpm,
                "torque_nm": s.torque_nm,
                "temperature_c": reading.temperature_c,
                "vibration_g": reading.vibration_g,
                "step": self._segment_index,
                "phase": self._label,
            },
        )

    def _drain_after_stop(self) -> None:
        """Keep recording briefly after the stop (spin-down), never raising."""
        if self.stand is None or self.writer is None:
            return
        try:
            self._write_rest(self.stand.read_samples(), "stop")
        except Exception as exc:
            log.debug("no samples after stop: %s", exc)

    def _write_rest(self, samples: list[StandSample], phase: str) -> None:
        """Samples read with the motor stopped, written as they came (command at the scale's
        low end). A row without a voltage (a stand that reads none, once the FC's telemetry
        stops with the motor) is not written: it cannot be loaded, nor is spin-down a rest zero."""
        if self.writer is None:
            return
        for s in samples:
            if s.voltage_v is None:
                continue
            values = {"thrust_n": s.thrust_n, "voltage_v": s.voltage_v, "current_a": s.current_a,
                      "rpm": s.rpm, "torque_nm": s.torque_nm, "step": self._segment_index,
                      "phase": phase}  # fmt: skip
            self.writer.write(s.time_s, float(self.scale.lo), values)

    def _report(self, now: float) -> None:
        if self.monitor is None:
            return
        in_plan = self._phase == "plan"
        driver = self.plan.adaptive
        duration = self.plan.duration_s
        if driver is not None and in_plan:
            left = driver.time_left_s()
            duration = now - self._t0 + (left if left is not None else self.plan.duration_s)
        self.monitor(
            Status(
                time_s=now,
                elapsed_s=now - self._t0 if in_plan else 0.0,
                plan_duration_s=duration,
                segment=self._segment_index,
                segments=len(self.plan.segments) if driver is None else 0,
                label=self._label,
                throttle_pct=self._cmd_pct,
                throttle_native=float(self.scale.from_pct(self._cmd_pct)),
                reading=self._reading,
                margins=margins(self.limits, self._reading),
                phase=self._phase,
                wait_s=(self._t0 if in_plan else now) - self._start,
                telemetry=self._telemetry,
                sample=self._last_sample,
                plan_note="" if driver is None else driver.status_line(),
            )
        )


def record_sweep(
    plan: Plan,
    output: ThrottleOutput,
    stand: Stand,
    log_path: str,
    clock: Clock,
    *,
    limits: Limits | None = None,
    config: RunConfig | None = None,
    monitor: Callable[[Status], None] | None = None,
) -> RunResult:
    """Run ``plan`` and record it as a Ds log (``log_path`` + its ``.meta.json`` sidecar, with
    ``config.sidecar``'s fields)."""
    limits = limits or Limits()
    config = config or RunConfig()
    check_plan(plan, limits)
    ident = output.identify()
    if limits.cells is None and ident.battery_cells:
        limits = Limits(**{**limits.to_dict(), "cells": ident.battery_cells})
    writer = DsWriter(
        log_path,
        output.throttle_scale,
        {
            "rotors_on_esc": config.rotors_on_esc,
            "strategy": "MR" if config.rotors_on_esc > 1 else "SR",
            "motor": config.motor,
            "devices": {"throttle_output": ident.to_dict(), "stand": stand.identify().to_dict()},
            "plan": plan.to_dict(),
            "limits": limits.to_dict(),
            "run_config": {k: v for k, v in config.__dict__.items() if k != "sidecar"},
            **dict(config.sidecar),
        },
    )
    return Runner(
        plan, output, stand, writer, clock, limits=limits, config=config, monitor=monitor
    ).run()
