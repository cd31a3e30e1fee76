"""Tyto Robotics Flight Stand (15/50/150/500) through its official Python API.

The Flight Stand core software runs on the bench computer and serves a gRPC service on
localhost:50051; Tyto's package ``flightstand`` ships its generated classes
(``FlightStand.flight_stand_api_v1_pb2*``). Every message thrustmap sends is built from them.
thrustmap does not use the package's ``FlightStand`` helper class: it prints, calls ``exit()``
when the core is not there, and clears any active cutoff when it is constructed, which
thrustmap must never do silently.

URL: ``flightstand://HOST:PORT`` with options ``?board=NAME`` (a board's resource name, path,
display name or serial; needed when several boards are connected), ``clear_cutoff=1`` (clear a
cutoff the core holds before starting, said in a warning; without it thrustmap refuses to start
on an active cutoff) and ``timeout=S`` (the deadline of each call, default 1 s).

- ``FlightStandStand``: the board's inputs mapped to thrustmap's streams (thrust ``FORCE_FZ``,
  torque ``TORQUE_MZ``, voltage, current, rotation speed, temperature, the ESC signal read back),
  every sample group the core streams through ``WatchSamples`` (the stream the service offers
  for live data: 10 Hz, fixed), stamped with the core's sample times;
  tare through ``TareInputs``; thrustmap's limits installed as the inputs' user cutoffs (only
  ever tightened, restored on close).
- ``FlightStandEscOutput``: the board's ESC output as the throttle output (PWM µs). While it is
  open it sends the heartbeat the core requires (``GetServerStatus`` every 0.25 s), so the
  core's own cutoff stops the ESC when thrustmap dies or the link drops. A cutoff the core raises
  aborts the run naming it (``FlightStandCutoff``); thrustmap never clears it. The stop is the
  output's cutoff target value (the value the core itself uses to stop the motor), verified by
  reading the output back and a newer sample of its signal.

Assumed units (the package does not state them): rotation speed in Hz (revolutions per second),
temperatures in °C.

The gRPC link itself (URL, calls with deadlines, the heartbeat and sample-stream threads) is
``rig.stand.flightstand_client``.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping
from typing import Any

from thrustmap.core.clock import Clock
from thrustmap.core.errors import ConfigError, SafetyError, ThrustmapError
from thrustmap.core.units import SCALES
from thrustmap.rig.interfaces import (
    DeviceAbort,
    DeviceIdentity,
    Stand,
    StandSample,
    Telemetry,
    ThrottleOutput,
)
from thrustmap.rig.stand.flightstand_client import (
    FlightStandClient,
    FlightStandError,
    parse_url,
    seconds_of,
)

__all__ = [
    "FACTORS",
    "LIMIT_STREAMS",
    "NEGATIVE_THRUST_ESC_FRACTION",
    "NEGATIVE_THRUST_N",
    "NEGATIVE_THRUST_SAMPLES",
    "STREAMS",
    "TARE_TIMEOUT_S",
    "VERIFY_WAIT_S",
    "FlightStandCutoff",
    "FlightStandEscOutput",
    "FlightStandStand",
    "ThrustReadsNegative",
    "describe_cutoff",
    "open_flightstand",
]

log = logging.getLogger(__name__)

TARE_TIMEOUT_S = 10.0
#: thrust below this while the ESC is well above its stop is not a pulling propeller's ...
NEGATIVE_THRUST_N = -0.05
NEGATIVE_THRUST_ESC_FRACTION = 0.15  # ... above the stop by this fraction of the range ...
NEGATIVE_THRUST_SAMPLES = 5  # ... in this many samples in a row (0.5 s at 10 Hz)
VERIFY_WAIT_S = 1.0  # for a sample of the ESC signal taken after the stop

#: thrustmap stream -> the core's input types for it, in order of preference
STREAMS: dict[str, tuple[str, ...]] = {
    "thrust_n": ("FORCE_FZ",),
    "torque_nm": ("TORQUE_MZ",),
    "voltage_v": ("VOLTAGE_HV_INPUT",),
    "current_a": ("CURRENT_HALL_CURRENT",),
    "rpm": ("ROTATION_SPEED_FREQUENCY",),
    "temperature_c": ("TEMPERATURE_PROBE", "TEMPERATURE_IR", "TEMPERATURE_PT100"),
    "esc_us": ("OUTPUT_VALUE_ESC_SIGNAL",),
}
#: stream -> factor from the core's value (SI; rotation speed assumed in Hz)
FACTORS = {"rpm": 60.0}
#: limit field -> the stream its cutoff is installed on
LIMIT_STREAMS = {
    "max_thrust_n": "thrust_n",
    "max_current_a": "current_a",
    "max_temperature_c": "temperature_c",
}


class FlightStandCutoff(DeviceAbort):
    """The Flight Stand core holds a cutoff: its outputs are at their cutoff targets."""


class ThrustReadsNegative(DeviceAbort):
    """The thrust input reads a pulling propeller negative: the data would be unusable."""


def describe_cutoff(condition: Any, fs: Any, inputs: Mapping[str, Any]) -> str:
    """'OUT_OF_RANGE_SIGNAL: Thrust (/boards/x/inputs/thrust) 3.06 above its cutoff 3'."""
    kind = str(fs.CutoffConditionType.Name(condition.type))
    if not condition.HasField("cutoff_trigger_signal"):
        return kind
    signal = condition.cutoff_trigger_signal.name
    value = condition.cutoff_trigger_sample.value
    inp = inputs.get(signal)
    if inp is None:
        return f"{kind}: signal {signal} at {value:.4g}"
    what = f"{inp.display_name or inp.name} ({inp.name}) at {value:.4g}"
    if inp.has_max_user_cutoff and value > inp.max_user_cutoff:
        what += f", above its cutoff {inp.max_user_cutoff:.4g}"
    elif inp.has_min_user_cutoff and value < inp.min_user_cutoff:
        what += f", below its cutoff {inp.min_user_cutoff:.4g}"
    return f"{kind}: {what}"


class FlightStandStand(Stand):
    """One board of a Flight Stand core as thrustmap's stand (see module)."""

    def __init__(self, url: str, clock: Clock, *, client: FlightStandClient | None = None) -> None:
        self.url = url
        self.clock = clock
        self.options = parse_url(url)
        self.client = client or FlightStandClient(
            self.options.address, timeout_s=self.options.timeout_s
        )
        self.fs = self.client.fs
        self._offset_s: float | None = None
        self._dropped_said = 0
        self._negative_run = 0
        self.esc_range_us: tuple[float, float] | None = None  # (stop, top), set by the output
        self._saved_cutoffs: dict[str, Any] = {}  # input name -> its original Input
        #: the heartbeat may go unanswered this long before the output reports a lost link
        self.link_timeout_s = 2.0 * self.options.timeout_s
        self.drives_esc = False
        try:
            self._discover()
            #: the cutoff the core held when the stand was opened (commanding refuses it)
            self.cutoff_at_open = self.cutoff()
            self.client.start_watch()
        except BaseException:
            self.client.close()
            raise

    # -- discovery ----------------------------------------------------------------------------
    def _discover(self) -> None:
        fs = self.fs
        try:
            boards = self.client.call("ListBoards", fs.ListBoardsRequest()).boards
        except FlightStandError as exc:
            raise ConfigError(
                f"cannot reach a Flight Stand core at {self.options.address} ({exc}); is the "
                "Flight Stand software (or `thrustmap sim-serve flightstand`) running?"
            ) from None
        ready = [b for b in boards if b.ready and not b.disconnected]
        self.board = self._choose(ready)
        prefix = f"{self.board.name}/"
        inputs = [i for i in self.client.call("ListInputs", fs.ListInputsRequest()).inputs
                  if i.name.startswith(prefix) and not i.closed]  # fmt: skip
        outputs = [o for o in self.client.call("ListOutputs", fs.ListOutputsRequest()).outputs
                   if o.name.startswith(prefix) and not o.closed]  # fmt: skip
        self.inputs: dict[str, Any] = {}  # stream -> fs.Input
        for stream, type_names in STREAMS.items():
            for type_name in type_names:
                found = [i for i in inputs if i.input_type == fs.InputType.Value(type_name)]
                if found:
                    if len(found) > 1:
                        log.info(
                            "%s: %d %s inputs, using %s",
                            self.url,
                            len(found),
                            type_name,
                            found[0].name,
                        )
                    self.inputs[stream] = found[0]
                    break
        if "thrust_n" not in self.inputs:
            raise ConfigError(
                f"{self.url}: board {self.board.name} has no thrust input (FORCE_FZ); inputs: "
                + (
                    ", ".join(f"{i.name} {fs.InputType.Name(i.input_type)}" for i in inputs)
                    or "none"
                )
            )
        self.by_signal = {i.signal_name: i for i in inputs}
        self.streams_by_signal = {i.signal_name: s for s, i in self.inputs.items()}
        escs = [o for o in outputs if o.output_type == fs.ESC]
        self.esc = escs[0] if escs else None
        try:
            stats = self.client.call("ListSignalStats", fs.ListSignalStatsRequest()).signal_stats
            rates = {s.signal_name: s.update_rate_hz for s in stats}
            self.rate_hz: float | None = rates.get(self.inputs["thrust_n"].signal_name)
        except FlightStandError:
            self.rate_hz = None

    def _choose(self, boards: list[Any]) -> Any:
        def names(b: Any) -> set[str]:
            ident = dict(b.identification)
            return {b.name, b.path, ident.get("displayName", ""), ident.get("serialNumber", "")} - {
                ""
            }

        def label(b: Any) -> str:
            shown = dict(b.identification).get("displayName", "")
            return f"{b.name} ({shown})" if shown else b.name

        where = self.options.address
        if self.options.board is not None:
            match = [b for b in boards if self.options.board in names(b)]
            if len(match) == 1:
                return match[0]
            listed = ", ".join(label(b) for b in boards) or "none"
            if not match:
                raise ConfigError(
                    f"no board '{self.options.board}' ready on the Flight Stand core at {where}; boards: {listed}"
                )
            raise ConfigError(
                f"board '{self.options.board}' names {len(match)} boards on {where}: {listed}"
            )
        if not boards:
            raise ConfigError(
                f"no board is ready on the Flight Stand core at {where}: connect the stand (or create a simulated board)"
            )
        if len(boards) > 1:
            raise ConfigError(
                f"{len(boards)} boards on the Flight Stand core at {where}: "
                f"{', '.join(label(b) for b in boards)}; choose one: flightstand://{where}?board=NAME"
            )
        return boards[0]

    # -- cutoff ---------------------------------------------------------------------------------
    def cutoff(self) -> str | None:
        """The core's active cutoff, described, or None."""
        core = self.client.call("GetCore", self.fs.GetCoreRequest())
        if not core.HasField("cutoff_active"):
            return None
        return describe_cutoff(core.cutoff_active, self.fs, self.by_signal)

    def check_cutoff(self, *, at_start: bool = False) -> None:
        """Raise ``FlightStandCutoff`` while the core holds a cutoff. At the start, with
        ``clear_cutoff=1`` in the URL, clear it instead (a warning says which)."""
        active = self.cutoff()
        if active is None:
            return
        if at_start and self.options.clear_cutoff:
            log.warning("clearing the Flight Stand core's cutoff (%s), as the URL asks", active)
            try:
                self.client.call("ClearCutoff", self.fs.ClearCutoffRequest())
            except FlightStandError as exc:
                raise FlightStandCutoff(
                    f"the Flight Stand core's cutoff ({active}) cannot be cleared: {exc}"
                ) from None
            return
        if at_start:
            raise FlightStandCutoff(
                f"the Flight Stand core at {self.options.address} holds a cutoff ({active}): "
                f"check the stand, then clear it in the Flight Stand software or add "
                f"?clear_cutoff=1 to the URL"
            )
        raise FlightStandCutoff(f"the Flight Stand core cut off the stand: {active}")

    # -- Stand ----------------------------------------------------------------------------------
    def identify(self) -> DeviceIdentity:
        fs = self.fs
        ident = dict(self.board.identification)
        sensors = ", ".join(
            f"{stream} <- {i.display_name or i.name} ({fs.InputType.Name(i.input_type)})"
            for stream, i in self.inputs.items()
        )
        details = {
            "core": self.options.address,
            "board_name": self.board.name,
            "sensors": sensors,
            "esc_output": "none" if self.esc is None else
            f"{self.esc.name} ({fs.OutputProtocolType.Name(self.esc.protocol)}, "
            f"{self.esc.min_user_value:g}-{self.esc.max_user_value:g} µs)",
        }  # fmt: skip
        if self.cutoff_at_open is not None:
            details["cutoff_active"] = self.cutoff_at_open
        if self.rate_hz:
            details["sample_rate"] = (
                f"{self.rate_hz:g} Hz at the core, 10 Hz streamed (WatchSamples)"
            )
        if ident.get("serialNumber"):
            details["serial"] = ident["serialNumber"]
        return DeviceIdentity(
            kind="flightstand",
            board=ident.get("displayName", self.board.name),
            firmware_version=ident.get("firmwareVersion", ""),
            details=details,
        )

    def read_samples(self) -> list[StandSample]:
        if self.client.watch_error is not None:
            raise FlightStandError(
                f"Flight Stand core at {self.options.address}: {self.client.watch_error}"
            )
        groups = self.client.take_groups()
        if self.client.groups_dropped > self._dropped_said:
            log.warning(
                "%d sample groups from the Flight Stand core were dropped (read too slowly)",
                self.client.groups_dropped - self._dropped_said,
            )
            self._dropped_said = self.client.groups_dropped
        out = []
        thrust_signal = self.inputs["thrust_n"].signal_name
        for group in groups:
            values: dict[str, float] = {}
            stamp: float | None = None
            for sample in group.samples:
                stream = self.streams_by_signal.get(sample.signal_name)
                if stream is None:
                    continue
                values[stream] = sample.value * FACTORS.get(stream, 1.0)
                if sample.signal_name == thrust_signal:
                    stamp = seconds_of(sample.sample_time)
            if stamp is None or not math.isfinite(values.get("thrust_n", math.nan)):
                continue
            self._question_sign(values)
            if self._offset_s is None:
                self._offset_s = self.clock.now_s() - stamp
            out.append(
                StandSample(
                    time_s=stamp + self._offset_s,
                    thrust_n=values["thrust_n"],
                    torque_nm=values.get("torque_nm"),
                    voltage_v=values.get("voltage_v"),
                    current_a=values.get("current_a"),
                    rpm=values.get("rpm"),
                    temperature_c=values.get("temperature_c"),
                    throttle_native=values.get("esc_us") if self.drives_esc else None,
                )
            )
        return out

    def _question_sign(self, values: Mapping[str, float]) -> None:
        """A thrust that stays negative while the ESC output drives the motor is not used: the
        stand reads a pulling propeller negative (or the propeller is mounted to push)."""
        esc_us = values.get("esc_us")
        if self.esc_range_us is None or esc_us is None:
            return
        stop, top = self.esc_range_us
        driven = esc_us >= stop + NEGATIVE_THRUST_ESC_FRACTION * (top - stop)
        if driven and values["thrust_n"] < NEGATIVE_THRUST_N:
            self._negative_run += 1
        else:
            self._negative_run = 0
        if self._negative_run >= NEGATIVE_THRUST_SAMPLES:
            raise ThrustReadsNegative(
                f"the Flight Stand's thrust input reads {values['thrust_n']:.3g} N with the ESC at "
                f"{esc_us:g} µs: a pulling propeller must read positive; reverse the thrust input "
                "in the Flight Stand software (or check the propeller's direction)"
            )

    def tare(self, service: Callable[[], None] | None = None) -> None:
        """``TareInputs``, then wait until the core says it is done (``service`` between)."""
        fs = self.fs
        self.client.call("TareInputs", fs.TareInputsRequest(), timeout_s=TARE_TIMEOUT_S)
        deadline = self.clock.now_s() + TARE_TIMEOUT_S
        while self.client.call("GetCore", fs.GetCoreRequest()).inputs_taring:
            if self.clock.now_s() > deadline:
                raise FlightStandError(
                    f"the Flight Stand core was still taring after {TARE_TIMEOUT_S:.0f} s"
                )
            if service is not None:
                service()
            self.clock.sleep_s(0.05)
        self.client.take_groups()  # readings from before the tare
        log.info("Flight Stand inputs tared through the API")

    def install_limits(self, limits: Any) -> list[str]:
        """thrustmap's limits as the inputs' user cutoffs (thrust, current, temperature), only
        ever lowering one the user set; the originals are restored on close. Returns what was
        installed ("thrust_n <= 20 N", ...)."""
        fs = self.fs
        link_timeout_s = getattr(limits, "link_timeout_s", None)
        if link_timeout_s is not None and math.isfinite(link_timeout_s) and link_timeout_s > 0:
            self.link_timeout_s = float(link_timeout_s)
            # a call on a silent link must not outlast the link timeout
            self.client.timeout_s = min(self.client.timeout_s, self.link_timeout_s)
        done = []
        for field_name, stream in LIMIT_STREAMS.items():
            inp = self.inputs.get(stream)
            value = getattr(limits, field_name, None)
            if inp is None or value is None or not math.isfinite(value):
                continue
            if inp.has_max_user_cutoff and inp.max_user_cutoff <= value:
                done.append(f"{stream} <= {inp.max_user_cutoff:g} (the stand's own, kept)")
                continue
            self._saved_cutoffs.setdefault(inp.name, fs.Input().FromString(inp.SerializeToString()))
            update = fs.Input(name=inp.name, max_user_cutoff=value, has_max_user_cutoff=True)
            mask = _mask(["max_user_cutoff", "has_max_user_cutoff"])
            new = self.client.call("UpdateInput", fs.UpdateInputRequest(input=update, mask=mask))
            if not (
                new.has_max_user_cutoff
                and abs(new.max_user_cutoff - value) <= 1e-6 * max(1.0, value)
            ):
                raise FlightStandError(
                    f"the core did not take the cutoff {stream} <= {value:g} on {inp.name}"
                )
            self.inputs[stream] = new
            self.by_signal[new.signal_name] = new
            done.append(f"{stream} <= {value:g}")
        log.info("installed as the Flight Stand core's cutoffs: %s", "; ".join(done) or "none")
        return done

    def _restore_cutoffs(self) -> None:
        fs = self.fs
        for name, original in self._saved_cutoffs.items():
            update = fs.Input(name=name, max_user_cutoff=original.max_user_cutoff,
                              has_max_user_cutoff=original.has_max_user_cutoff)  # fmt: skip
            try:
                self.client.call("UpdateInput", fs.UpdateInputRequest(
                    input=update, mask=_mask(["max_user_cutoff", "has_max_user_cutoff"])))  # fmt: skip
            except FlightStandError as exc:
                log.warning("could not restore the user cutoff of %s: %s", name, exc)
        self._saved_cutoffs.clear()

    def close(self) -> None:
        try:
            self._restore_cutoffs()
        finally:
            self.client.close()


def _mask(paths: list[str]) -> Any:
    from google.protobuf.field_mask_pb2 import FieldMask

    return FieldMask(paths=paths)


class FlightStandEscOutput(ThrottleOutput):
    """The board's ESC output as the throttle output, in PWM µs (see module)."""

    throttle_scale = SCALES["pwm"]

    def __init__(self, stand: FlightStandStand, motor: int = 0) -> None:
        if stand.esc is None:
            raise ConfigError(f"{stand.url}: board {stand.board.name} has no ESC output")
        self.stand = stand
        self.client = stand.client
        self.fs = stand.fs
        self.motor = motor
        esc = stand.esc
        cut = esc.cutoff_target
        # the stop is the value the core itself stops the motor with
        self.stop_us = float(cut.target_value) if cut.active else float(esc.min_user_value)
        self.max_us = float(esc.max_user_value)
        self.step_us = float(esc.step_size)
        if not self.stop_us < self.max_us:
            raise ConfigError(
                f"{esc.name}: its stop value {self.stop_us:g} is not below its range top {self.max_us:g}"
            )
        self._commanded = False
        self._stop_sent_at: float | None = None  # core group time seen when the stop went out
        self._stop_verified = False  # verified since the last command
        self.esc: Any = esc
        stand.check_cutoff(at_start=True)  # never command over a cutoff; clear only if asked
        stand.esc_range_us = (self.stop_us, self.max_us)
        stand.drives_esc = True
        self.client.start_heartbeat()

    def identify(self) -> DeviceIdentity:
        esc = self.esc
        return DeviceIdentity(
            kind="flightstand-esc",
            board=self.stand.identify().board,
            motor_protocol=self.fs.OutputProtocolType.Name(esc.protocol),
            motor_count=1,
        )

    def _write(self, active: bool, value_us: float) -> None:
        fs = self.fs
        target = fs.OutputTarget(active=active, target_value=value_us)
        request = fs.UpdateOutputRequest(
            output=fs.Output(name=self.esc.name, output_target=target),
            mask=_mask(["output_target"]),
        )
        self.client.call("UpdateOutput", request)

    def _check_link(self) -> None:
        age = time.monotonic() - self.client.heartbeat_ok_s
        if age > self.stand.link_timeout_s:
            raise FlightStandError(
                f"no heartbeat answer from the Flight Stand core for {age:.1f} s"
                + (f" ({self.client.heartbeat_error})" if self.client.heartbeat_error else "")
            )

    def set_throttle(self, values: Mapping[int, float]) -> None:
        if set(values) - {self.motor}:
            raise SafetyError(
                f"the Flight Stand's ESC output drives one motor ({self.motor}), asked {sorted(values)}"
            )
        us = float(values.get(self.motor, self.stop_us))
        if not math.isfinite(us):
            raise SafetyError(f"throttle {us} µs is not a number")
        us = min(max(us, self.stop_us), self.max_us)
        self._check_link()
        try:
            self._write(True, us)
        except FlightStandError as exc:
            if self.client.code_of(exc) == "FAILED_PRECONDITION":
                self.stand.check_cutoff()  # raises naming the cutoff, if that was it
            raise
        self._commanded = True
        self._stop_sent_at = None
        self._stop_verified = False

    def keepalive(self) -> None:
        self._check_link()

    def stop(self) -> None:
        try:
            self._write(True, self.stop_us)
        except FlightStandError as exc:
            # under a cutoff the core holds the output at its cutoff target: verify reads it
            if self.client.code_of(exc) != "FAILED_PRECONDITION":
                raise
        # the newest group now: any group taken after it was taken after the stop was applied
        self._stop_sent_at = self._latest_group_time()

    def _latest_group_time(self) -> float:
        group = self.client.call("ListSamples", self.fs.ListSamplesRequest()).sample_group
        return seconds_of(group.group_time)

    def verify_stopped(self) -> bool:
        """The output's target is the stop (or the output is off), and a sample of its signal
        taken after the stop reads it back."""
        ok = self._verify()
        if ok and self._stop_sent_at is not None:
            self._stop_verified = True
        return ok

    def _verify(self) -> bool:
        esc = self.client.call("GetOutput", self.fs.GetOutputRequest(name=self.esc.name))
        target = esc.output_target
        if target.active and target.target_value > self.stop_us + self.step_us / 2:
            return False
        after = self._stop_sent_at if self._stop_sent_at is not None else -math.inf
        deadline = time.monotonic() + VERIFY_WAIT_S
        while True:  # a sample of the output's signal taken after the stop, reading the stop
            group = self.client.call("ListSamples", self.fs.ListSamplesRequest()).sample_group
            if seconds_of(group.group_time) > after:
                for sample in group.samples:
                    if sample.signal_name == esc.signal_name and (
                        not sample.active or sample.value <= self.stop_us + self.step_us / 2
                    ):
                        return True
            if time.monotonic() > deadline:
                return False  # no such readback (or none of the signal at all): not verified
            time.sleep(0.01)

    def read_telemetry(self) -> Telemetry:
        """Checks the core's cutoff (raises ``FlightStandCutoff`` naming it) and the heartbeat."""
        self._check_link()
        self.stand.check_cutoff()
        return Telemetry(self.stand.clock.now_s())

    def close(self) -> None:
        """Switch the ESC signal off once the stop was verified, then end the heartbeat (the
        core's own cutoff stops the output if it is still active then)."""
        try:
            if self._commanded and (self._stop_verified or self.verify_stopped()):
                self._write(False, self.stop_us)
        except ThrustmapError as exc:
            log.warning("could not switch the ESC signal off after the stop: %s", exc)
        finally:
            self.client.stop_heartbeat()


def open_flightstand(url: str, clock: Clock) -> FlightStandStand:
    return FlightStandStand(url, clock)
