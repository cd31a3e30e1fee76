"""Simulated thrust stands at the byte level (``BytePeer``s): a Tyto Series 1585 and a line stand.

Both drive plant motor ``motor`` (default 0) themselves, like the real stands drive their ESC,
and report the plant's load cell at the current time.

- :class:`TytoStandPeer` prints ``Ready\\r\\n`` ``boot_s`` after the port opens (its first call),
  ignores everything before that, and answers each poll (code 3) with the 58-byte reply: raw
  load-cell counts computed through the inverse of a :class:`TytoCalibration`, so a driver
  using the same calibration reads the plant's thrust and torque back. The polled ESC µs sets
  the throttle ((µs - 1000) / 1000).
- :class:`LineStandPeer` prints ``#`` banner lines and the spec's header, then streams one data
  line every ``1 / rate_hz`` seconds computed from the plant at that instant. It obeys the
  spec's throttle/stop commands (parsed back through the command template), answers unknown
  lines with ``#ERR <line>``, and, when the spec has a ``watchdog_s``, stops the motor and
  prints ``#WATCHDOG`` when no line has arrived for that long.
"""

from __future__ import annotations

import logging
import random
from collections.abc import Callable, Collection, Mapping

from thrustmap.core.errors import ConfigError
from thrustmap.core.units import scale as lookup_scale
from thrustmap.protocols.peer import BytePeer, register_peer
from thrustmap.protocols.stands.line import REFERENCE, LineStandSpec
from thrustmap.protocols.stands.line_presets import preset
from thrustmap.protocols.stands.tyto import (
    TYTO_POLL_CODE,
    TYTO_READY_LINE,
    LoadCell,
    TytoCalibration,
    TytoDecoder,
    TytoPayloadError,
    TytoPoll,
    TytoReading,
)
from thrustmap.rig.sim.options import opt_flag, opt_float
from thrustmap.rig.sim.plant import ConstantPlant, Plant

log = logging.getLogger(__name__)

#: The calibration the simulated Tyto uses unless given one (HX711-like raw counts; a pulling
#: propeller lowers the thrust count, as on the real stand).
SIM_TYTO_CALIBRATION = TytoCalibration(
    thrust=LoadCell(tare=12000.0, n_per_count=-1e-4),
    torque_left=LoadCell(tare=300.0, n_per_count=2e-4),
    torque_right=LoadCell(tare=-250.0, n_per_count=2e-4),
    arm_length_m=0.0425,
    serial="SIM-1585",
)


class TytoStandPeer:
    def __init__(
        self,
        plant: Plant,
        calibration: TytoCalibration = SIM_TYTO_CALIBRATION,
        *,
        motor: int = 0,
        boot_s: float = 1.5,
        noise_counts: float = 0.0,
        rng: random.Random | None = None,
        drive_esc: bool = True,
    ) -> None:
        self.plant = plant
        #: False when a flight controller drives the ESC and the stand only measures
        self.drive_esc = drive_esc
        self.calibration = calibration
        self.motor = motor
        self.boot_s = boot_s
        self.noise_counts = noise_counts
        self._rng = rng if rng is not None else random.Random(0)
        self._decoder = TytoDecoder("<")
        self._outbox = bytearray()
        self._opened_s: float | None = None
        self._time_s = float("-inf")
        self.ready = False
        self.esc_us = 0
        self.polls = 0

    def _advance(self, now_s: float) -> float:
        if self._opened_s is None:
            self._opened_s = now_s
        self._time_s = max(self._time_s, now_s)
        if not self.ready and self._time_s >= self._opened_s + self.boot_s:
            self.ready = True
            self._outbox += f"{TYTO_READY_LINE}\r\n".encode()
        return self._time_s

    def write(self, data: bytes, now_s: float) -> None:
        t = self._advance(now_s)
        if not self.ready:
            return  # still booting: the bytes are lost
        for frame in self._decoder.feed(data):
            if frame.code != TYTO_POLL_CODE:
                log.debug("simulated Tyto: ignoring code %d", frame.code)
                continue
            try:
                poll = TytoPoll.decode(frame.payload)
            except TytoPayloadError as exc:
                log.debug("simulated Tyto: %s", exc)
                continue
            self.polls += 1
            self.esc_us = poll.esc_us
            if self.drive_esc:
                fraction = min(max((poll.esc_us - 1000) / 1000.0, 0.0), 1.0)
                self.plant.set_throttle(self.motor, fraction, t)
            self._outbox += self._reading(t).frame()

    def read(self, now_s: float) -> bytes:
        self._advance(now_s)
        out = bytes(self._outbox)
        self._outbox.clear()
        return out

    def _noise(self) -> float:
        return self._rng.gauss(0.0, self.noise_counts) if self.noise_counts else 0.0

    def _reading(self, t: float) -> TytoReading:
        state = self.plant.state(t)
        cal = self.calibration
        thrust, left, right = cal.raw_counts(state.thrust_n, state.torque_nm)
        rpm = state.rpm[self.motor] if self.motor < len(state.rpm) else 0.0
        temps = list(state.temperature_c[self.motor : self.motor + 1]) or [25.0]
        vib = 0
        if cal.vibration_g_per_count:
            vib = int(round(state.vibration_g / cal.vibration_g_per_count))
        return TytoReading(
            esc_voltage=state.voltage_v,
            esc_current=state.current_a,
            esc_power=state.voltage_v * state.current_a,
            load_thrust=thrust + self._noise(),
            load_left=left + self._noise(),
            rot_e=rpm / cal.electrical_rpm_factor,
            rot_o=rpm / cal.optical_rpm_factor,
            temp0=temps[0],
            temp1=25.0,
            temp2=25.0,
            basic_data_flag=1,
            acc_x=0,
            acc_y=0,
            acc_z=0,
            vibration=max(-0x8000, min(0x7FFF, vib)),
            raw_pressure_p=0,
            raw_pressure_t=0,
            load_right=right + self._noise(),
            pro_data_flag=1,
        )


class LineStandPeer:
    def __init__(
        self,
        plant: Plant,
        spec: LineStandSpec = REFERENCE,
        *,
        rate_hz: float = 100.0,
        motor: int = 0,
        banner: tuple[str, ...] = ("thrustmap simulated line stand",),
        max_backlog_s: float = 5.0,
    ) -> None:
        if rate_hz <= 0:
            raise ConfigError(f"line stand rate must be > 0 Hz, got {rate_hz}")
        self.plant = plant
        self.spec = spec
        self.period_s = 1.0 / rate_hz
        self.motor = motor
        self.banner = banner
        self.max_backlog_s = max_backlog_s
        self._outbox = bytearray()
        self._rx = bytearray()
        self._start_s: float | None = None
        self._next_k = 0  # index of the next sample: t = start + k * period
        self._last_rx_s: float | None = None
        self.throttle_pct = 0.0
        self.label_pct = 0.0  # what a stand that drives no ESC echoes in its throttle column
        self.watchdog_trips = 0
        self.lines_sent = 0
        #: the firmware's own sequence once started: (time, level) changes and row times
        self._sequence: list[tuple[float, str, float]] = []
        self.sequences_run = 0
        self.resets = 0

    # -- BytePeer -----------------------------------------------------------------------------
    def write(self, data: bytes, now_s: float) -> None:
        self._emit_until(now_s)
        self._rx += data
        while True:
            cut = min(
                (i for i in (self._rx.find(b"\n"), self._rx.find(b"\r")) if i >= 0), default=-1
            )
            if cut < 0:
                if len(self._rx) > 4096:
                    self._rx.clear()
                return
            line = self._rx[:cut].decode("utf-8", errors="replace").strip()
            del self._rx[: cut + 1]
            if line:
                self._command(line, now_s)

    def read(self, now_s: float) -> bytes:
        self._emit_until(now_s)
        out = bytes(self._outbox)
        self._outbox.clear()
        return out

    # -- internals ----------------------------------------------------------------------------
    def _say(self, line: str) -> None:
        self._outbox += (line + "\n").encode()

    def _set_pct(self, pct: float, t: float) -> None:
        self.throttle_pct = pct
        self.plant.set_throttle(self.motor, pct / 100.0, t)

    def _command(self, line: str, now_s: float) -> None:
        self._last_rx_s = now_s
        spec = self.spec
        if spec.sequence_start is not None and line == spec.sequence_start.strip():
            if not self._sequence:
                self._start_sequence(now_s)
            return
        pct = spec.parse_command(line)
        if pct is not None and not spec.drives_esc:
            self.label_pct = pct  # only printed back: the FC drives the motor
            return
        if pct is not None:
            self._set_pct(pct, now_s)
            return
        if spec.sequence_start is not None:
            return  # a firmware that only waits for its start byte ignores everything else
        keepalive = self.spec.keepalive
        if keepalive is not None and line == keepalive.strip():
            return
        self._say(f"{self.spec.comment_prefix}ERR {line[:60]}")

    def _watchdog(self, t: float) -> None:
        wd = self.spec.watchdog_s
        if wd is None or self.throttle_pct == 0.0 or self._last_rx_s is None:
            return
        trip_s = self._last_rx_s + wd
        if trip_s <= t:
            self._set_pct(0.0, trip_s)
            self.watchdog_trips += 1
            log.info("simulated line stand: watchdog stopped the motor at %.3f s", trip_s)
            self._say(f"{self.spec.comment_prefix}WATCHDOG")

    def set_dtr(self, asserted: bool, now_s: float) -> None:
        """DTR asserted resets a board that resets by it (``reset_stops``): the output stops,
        its own sequence is forgotten, and it waits again for its start command."""
        self._emit_until(now_s)
        if asserted and self.spec.reset_stops:
            self._sequence.clear()
            self._set_pct(0.0, now_s)
            self.resets += 1

    # -- a firmware that runs its own sequence ---------------------------------------------
    def _start_sequence(self, t: float) -> None:
        spec = self.spec
        scale = lookup_scale(spec.throttle_scale)
        at = t
        for level in spec.sequence_levels:
            pct = float(scale.to_pct(level))
            self._sequence.append((at, "set", pct))
            at += spec.sequence_settle_s
            for _ in range(spec.sequence_rows):
                at += spec.sequence_row_period_s
                self._sequence.append((at, "row", pct))
        self._sequence.append((at, "end", 0.0))
        self.sequences_run += 1

    def _emit_sequence(self, now_s: float) -> None:
        while self._sequence and self._sequence[0][0] <= now_s:
            t, what, pct = self._sequence.pop(0)
            if what == "set":
                self._set_pct(pct, t)
            elif what == "row":
                self._row(t, now_s)
            else:
                self._set_pct(0.0, t)
                if self.spec.sequence_end is not None:
                    self._say(self.spec.sequence_end)

    def _row(self, t: float, now_s: float) -> None:
        assert self._start_s is not None
        scale = lookup_scale(self.spec.throttle_scale)
        try:
            state = self.plant.state(t)
        except ValueError:  # a simulated FC on the same bench has moved the plant past t
            state = self.plant.state(now_s)
        rpm = state.rpm[self.motor] if self.motor < len(state.rpm) else 0.0
        pct = self.throttle_pct if self.spec.drives_esc else self.label_pct
        values = {
            "time_s": t - self._start_s,
            "throttle": float(scale.from_pct(pct)),
            "thrust_n": state.thrust_n,
            "torque_nm": state.torque_nm,
            "voltage_v": state.voltage_v,
            "current_a": state.current_a,
            "rpm": rpm,
        }
        self._say(self.spec.format_sample(values))
        self.lines_sent += 1

    def _emit_until(self, now_s: float) -> None:
        if self._start_s is None:
            self._start_s = now_s
            if self.spec.header_prefix is not None:  # a firmware with no header prints no banner
                for text in self.banner:
                    self._say(f"{self.spec.comment_prefix} {text}")
            header = self.spec.header_line()
            if header is not None:
                self._say(header)
        if self.spec.sequence_start is not None:
            self._emit_sequence(now_s)  # silent but for its own sequence
            return
        start = self._start_s
        # the last sample due by now (a tiny epsilon absorbs float error in k * period)
        last_k = int((now_s - start) / self.period_s + 1e-9)
        backlog_k = int(self.max_backlog_s / self.period_s)
        if last_k - self._next_k > backlog_k:  # a real port would drop these lines
            self._watchdog(start + (last_k - backlog_k) * self.period_s)
            self._next_k = last_k - backlog_k
        while self._next_k <= last_k:
            t = start + self._next_k * self.period_s
            self._watchdog(t)
            self._row(t, now_s)
            self._next_k += 1


# --------------------------------------------------------------------------- sim:// factories


def _float_opt(options: Mapping[str, str], key: str, default: float) -> float:
    return opt_float(options, key, default, minimum=0.0)


def _check(options: Mapping[str, str], known: set[str], what: str, allow: Collection[str]) -> None:
    unknown = set(options) - known - set(allow)
    if unknown:
        raise ConfigError(f"unknown {what} sim options {sorted(unknown)}; expected {sorted(known)}")


def tyto_peer_from_options(
    options: Mapping[str, str], plant: Plant | None = None, *, allow: Collection[str] = ()
) -> TytoStandPeer:
    """``sim://tyto-1585?calibration=cal.json&boot_s=1.5&noise_counts=2``."""
    _check(options, {"calibration", "boot_s", "noise_counts", "drive_esc"}, "Tyto", allow)
    from thrustmap.rig.stand.tyto import load_calibration

    cal = SIM_TYTO_CALIBRATION
    if "calibration" in options:
        cal = load_calibration(options["calibration"])
    return TytoStandPeer(
        plant if plant is not None else ConstantPlant(1),
        cal,
        boot_s=_float_opt(options, "boot_s", 1.5),
        noise_counts=_float_opt(options, "noise_counts", 0.0),
        drive_esc=opt_flag(options, "drive_esc", True),
    )


def line_peer_from_options(
    options: Mapping[str, str], plant: Plant | None = None, *, allow: Collection[str] = ()
) -> BytePeer:
    """``sim://line-stand?preset=thrustmap-line&rate_hz=100``; a preset whose firmware has its
    own simulator (``rig.sim.diy_stand_peers``) gets that one, at the firmware's own rate."""
    from thrustmap.rig.sim.diy_stand_peers import FIRMWARE_PEERS

    _check(options, {"preset", "rate_hz"}, "line stand", allow)
    spec = preset(options.get("preset", REFERENCE.name))
    if spec.name in FIRMWARE_PEERS:
        if "rate_hz" in options:
            raise ConfigError(f"sim line stand '{spec.name}' prints at its firmware's own rate")
        return FIRMWARE_PEERS[spec.name](plant if plant is not None else ConstantPlant(1), spec)
    return LineStandPeer(
        plant if plant is not None else ConstantPlant(1),
        spec,
        rate_hz=opt_float(options, "rate_hz", 100.0, positive=True, what="a rate in Hz"),
    )


def register_stand_peers(
    plant_factory: Callable[[Mapping[str, str]], Plant] = lambda options: ConstantPlant(1),
    *,
    plant_options: Collection[str] = (),
    replace: bool = True,
) -> None:
    """Register ``sim://tyto-1585`` and ``sim://line-stand``."""

    def tyto(options: Mapping[str, str]) -> BytePeer:
        return tyto_peer_from_options(options, plant_factory(options), allow=plant_options)

    def line(options: Mapping[str, str]) -> BytePeer:
        return line_peer_from_options(options, plant_factory(options), allow=plant_options)

    from thrustmap.rig.stand.tyto import register_simulated_calibration

    register_peer("tyto-1585", tyto, replace=replace)
    register_peer("line-stand", line, replace=replace)
    # what a driver opening sim://tyto-1585 without ?calibration= reads the raw counts with
    register_simulated_calibration("tyto-1585", SIM_TYTO_CALIBRATION)
