"""A simulated Tyto Flight Stand core: the package's gRPC service with thrustmap's physics behind.

The real Flight Stand core software runs on the bench computer and serves the ``FlightStand``
gRPC service (``flight_stand_api_v1.proto``, shipped generated in the official ``flightstand``
package) on localhost:50051. This server implements that service, built from the package's own
generated classes, for the calls the official client (the ``FlightStand`` helper class and its
``examples/example.py`` and ``data_recording.py``) and thrustmap's driver make:

- boards (``ListBoards``, ``GetBoard``, ``CreateSimulatedBoard``, ``DisconnectBoard``): each
  board is one stand with one ESC output and its own ``PhysicsPlant`` (motor, ESC, battery);
- inputs (thrust ``FORCE_FZ``, torque ``TORQUE_MZ``, voltage, current, rotation speed, motor
  temperature, the ESC signal read back) and outputs (``ESC``, standard PWM in µs), with the
  user cutoff range of each input (``UpdateInput``) enforced as a cutoff condition;
- samples (``ListSamples``: the latest group; ``WatchSamples``: the bidirectional stream the
  service documents, fixed at 10 Hz, one response per acknowledging request), stamped with the
  core's sample time;
- tare (``TareInputs``), the cutoff (``TriggerCutoff``, ``ClearCutoff`` refused while a condition
  holds, ``ListCutoffConditions``, ``GetCore.cutoff_active``) and the heartbeat
  (``GetServerStatus``), and the test recorder (manual samples, continuous recording, save,
  ``ListTestData`` with resampling and pagination).

Units: the API is SI, so thrust is N, torque N·m, voltage V, current A. Two units the package
does not state are assumptions of this simulator: the rotation speed ``ROTATION_SPEED_FREQUENCY``
is in Hz (revolutions per second) and temperatures are in °C.

The heartbeat, as the service's own documentation says: "If this function is not called at least
once per second, the core will trigger a cutoff ... If the GUI is running, the user script does
not have to regularly call this rpc." The simulator stands for a core whose GUI is open until a
client heartbeats (two ``GetServerStatus`` calls less than ``no_client_timeout_s`` apart); from
then on, a gap longer than ``no_client_timeout_s`` while an output is active triggers a
``NO_CLIENT`` cutoff (when no output is active the gap only ends the heartbeating client).
Whether the real core also cuts off with every output inactive is not documented; that part of
the model is an assumption.

Time is real (the server's monotonic clock for the physics, the wall clock for sample stamps):
this is a stand for clients that run in real time.

This module is the core itself; ``rig.sim.flightstand_service`` serves it over gRPC
(``FlightStandServer``, ``serve``).
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from thrustmap.core.errors import ConfigError
from thrustmap.rig.sim.physics import PhysicsPlant, make_plant

log = logging.getLogger(__name__)

DEFAULT_PORT = 50051
#: the documented heartbeat: "at least once per second"
NO_CLIENT_TIMEOUT_S = 1.0
PWM_STOP_US = 1000.0
PWM_MAX_USER_US = 2000.0
PWM_MAX_SYSTEM_US = 2301.0  # half-open: 2300 µs is the largest value (see Output's docs)
#: system cutoffs of the simulated Flight Stand 50's sensors (generous; the user sets lower)
SYSTEM_CUTOFFS = {"FORCE_FZ": 500.0, "TORQUE_MZ": 50.0, "CURRENT_HALL_CURRENT": 150.0}
HISTORY_GROUPS = 4000  # sample groups kept for ListSamples, tare and the watchers
RECORDING_MAX_GROUPS = 360_000  # one hour at 100 Hz: continuous recording stops beyond this
MAX_WATCHERS = 8
WATCH_RATE_HZ = 10.0  # WatchSamples: "The sample rate is fixed at 10 Hz and cannot be configured"
WATCH_BUFFER_GROUPS = 100  # what WatchSamples keeps for a slow client ("up to a reasonable limit")


def _fs() -> Any:
    """The official package's generated messages (``FlightStand.flight_stand_api_v1_pb2``)."""
    os.environ.setdefault("GRPC_VERBOSITY", "NONE")  # errors are said in one line, not by gRPC
    try:
        import FlightStand  # noqa: F401  (registers the generated modules' absolute names)
        from FlightStand import flight_stand_api_v1_pb2 as fs
    except ImportError as exc:  # pragma: no cover - the extra is not installed
        raise ConfigError(
            f"the simulated Flight Stand core needs the official package: "
            f"pip install 'thrustmap[flightstand]' ({exc})"
        ) from None
    return fs


# Inputs of each simulated board: (id, InputType name, display name, has_tare)
INPUTS: tuple[tuple[str, str, str, bool], ...] = (
    ("thrust", "FORCE_FZ", "Thrust", True),
    ("torque", "TORQUE_MZ", "Torque", True),
    ("voltage", "VOLTAGE_HV_INPUT", "Voltage", False),
    ("current", "CURRENT_HALL_CURRENT", "Current", False),
    ("rotation", "ROTATION_SPEED_FREQUENCY", "Rotation speed", False),
    ("temperature", "TEMPERATURE_PROBE", "Motor temperature", False),
    ("esc_signal", "OUTPUT_VALUE_ESC_SIGNAL", "ESC signal", False),
)


@dataclass
class Board:
    name: str
    display_name: str
    serial: str
    plant: PhysicsPlant
    inputs: dict[str, Any] = field(default_factory=dict)  # input id -> fs.Input
    esc: Any = None  # fs.Output
    esc_value_us: float = PWM_STOP_US
    esc_active: bool = False
    esc_changed_wall_s: float = 0.0


def _signal_id(board: Board, name: str) -> str:
    return f"/signals/{board.name.rsplit('/', 1)[-1]}_{name}"


class FlightStandCore:
    """The simulated core's state and its sampler thread (the servicer is ``servicer()``)."""

    def __init__(
        self,
        *,
        plant: str = "xnova-2207-6s",
        seed: int = 1,
        noise: bool = True,
        rate_hz: float = 100.0,
        boards: int = 1,
        no_client_timeout_s: float = NO_CLIENT_TIMEOUT_S,
    ) -> None:
        if not 1.0 <= rate_hz <= 1000.0:
            raise ConfigError(f"sample rate {rate_hz:g} Hz: expected 1 to 1000 Hz")
        if not 0 <= boards <= 8:
            raise ConfigError(f"{boards} boards: expected 0 to 8")
        self.fs = _fs()
        self.plant_name = plant
        self.seed = seed
        self.noise = noise
        self.period_s = 1.0 / rate_hz
        self.no_client_timeout_s = no_client_timeout_s
        self.lock = threading.RLock()
        self.new_group = threading.Condition(self.lock)
        self.boards: dict[str, Board] = {}
        self._board_serial = 0
        self.history: deque[Any] = deque(maxlen=HISTORY_GROUPS)  # fs.SampleGroup
        self.group_count = 0
        self.cutoff: Any = None  # fs.CutoffCondition while a cutoff is active
        self.last_poll_s: float | None = None
        self.heartbeating = False
        self.watchers = 0
        self.watch_history: deque[Any] = deque(maxlen=WATCH_BUFFER_GROUPS)  # the 10 Hz groups
        self.watch_count = 0
        self._watch_every = max(1, round(rate_hz / WATCH_RATE_HZ))
        # the test recorder
        self.recorder_title = ""
        self.manual: list[Any] = []
        self.continuous: list[Any] | None = None
        self.segments: list[list[Any]] = []
        self.tests: dict[str, tuple[str, list[Any], list[list[Any]]]] = {}
        self._last_manual_s = -1e9
        self._stop = threading.Event()
        for _ in range(boards):
            self.add_board()
        self._thread = threading.Thread(target=self._run, name="flightstand-core", daemon=True)

    # -- boards -------------------------------------------------------------------------------
    def add_board(self) -> Board:
        fs = self.fs
        with self.lock:
            self._board_serial += 1
            n = self._board_serial
            plant = make_plant(self.plant_name, rotors_on_esc=1, seed=self.seed + n - 1,
                               noise=self.noise)  # fmt: skip
            board = Board(f"/boards/simulated_{n}", f"Flight Stand 50 (simulated {n})",
                           f"SIM-FS50-{n:04d}", plant)  # fmt: skip
            for ident, type_name, display, has_tare in INPUTS:
                system = SYSTEM_CUTOFFS.get(type_name, 0.0)
                board.inputs[ident] = fs.Input(
                    name=f"{board.name}/inputs/{ident}",
                    display_name=display,
                    input_type=fs.InputType.Value(type_name),
                    has_tare=has_tare,
                    signal_name=_signal_id(board, ident),
                    raw_signal_name=_signal_id(board, ident) + "_raw",
                    min_system_cutoff=-system,
                    max_system_cutoff=system,
                )
            board.esc = fs.Output(
                name=f"{board.name}/outputs/esc",
                display_name="ESC throttle",
                output_type=fs.ESC,
                supported_protocols=[fs.STANDARD_PWM_50_HZ, fs.STANDARD_PWM_400_HZ],
                protocol=fs.STANDARD_PWM_50_HZ,
                cutoff_target=fs.OutputTarget(active=True, target_value=PWM_STOP_US),
                output_target=fs.OutputTarget(active=False, target_value=PWM_STOP_US),
                signal_name=_signal_id(board, "esc_output"),
                min_system_value=PWM_STOP_US,
                max_system_value=PWM_MAX_SYSTEM_US,
                min_user_value=PWM_STOP_US,
                max_user_value=PWM_MAX_USER_US,
                step_size=1.0,
            )
            self.boards[board.name] = board
            log.info("simulated Flight Stand board %s connected", board.name)
            return board

    def board_message(self, board: Board) -> Any:
        fs = self.fs
        return fs.Board(
            name=board.name,
            path=board.name.rsplit("/", 1)[-1],
            ready=True,
            synchronized=True,
            is_sync_master=True,
            identification={
                "displayName": board.display_name,
                "serialNumber": board.serial,
                "boardType": "Flight Stand 50",
                "simulated": "true",
            },
        )

    # -- the physics and the sampler ----------------------------------------------------------
    def start(self) -> None:
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        with self.new_group:
            self.new_group.notify_all()

    @property
    def closed(self) -> bool:
        return self._stop.is_set()

    def has_news(self, seen: int) -> bool:
        """A 10 Hz group newer than the ``seen``-th was taken (or the core is closing)."""
        return self.watch_count > seen or self.closed

    def _run(self) -> None:
        next_s = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            if now < next_s:
                self._stop.wait(next_s - now)
                continue
            next_s = max(next_s + self.period_s, now - self.period_s)
            try:
                self._tick(now)
            except Exception:  # the sampler must keep running: log and go on
                log.exception("simulated Flight Stand core: sampler tick failed")

    def _apply_esc(self, board: Board, now_s: float) -> None:
        fraction = (board.esc_value_us - PWM_STOP_US) / 1000.0 if board.esc_active else 0.0
        board.plant.set_throttle(0, fraction, now_s)

    def _tick(self, now_s: float) -> None:
        fs = self.fs
        wall = time.time()
        with self.new_group:
            self._check_heartbeat(now_s)
            samples = []
            for board in self.boards.values():
                target = board.esc.output_target
                if (target.active, target.target_value) != (board.esc_active, board.esc_value_us):
                    board.esc_active = target.active
                    board.esc_value_us = target.target_value
                    board.esc_changed_wall_s = wall
                    self._apply_esc(board, now_s)
                st = board.plant.state(now_s)
                values = {
                    "thrust": st.thrust_n,
                    "torque": st.torque_nm,
                    "voltage": st.voltage_v,
                    "current": st.current_a,
                    "rotation": st.rpm[0] / 60.0 if st.rpm else 0.0,
                    "temperature": st.temperature_c[0] if st.temperature_c else 25.0,
                    "esc_signal": board.esc_value_us,
                }
                stamp = _timestamp(fs, wall)
                for ident, raw in values.items():
                    inp = board.inputs[ident]
                    value = raw - inp.tare_offset if inp.has_tare else raw
                    if inp.reversed:
                        value = -value
                    sample = fs.Sample(signal_name=inp.signal_name, active=True, value=value,
                                       filtered_value=value)  # fmt: skip
                    sample.sample_time.CopyFrom(stamp)
                    samples.append(sample)
                    if self.cutoff is None:
                        self._check_range(inp, sample)
                out = fs.Sample(signal_name=board.esc.signal_name, active=board.esc_active,
                                value=board.esc_value_us, filtered_value=board.esc_value_us)  # fmt: skip
                out.sample_time.CopyFrom(stamp)
                samples.append(out)
            group = fs.SampleGroup(samples=samples)
            group.group_time.CopyFrom(_timestamp(fs, wall))
            self.history.append(group)
            self.group_count += 1
            if self.group_count % self._watch_every == 0:
                self.watch_history.append(group)
                self.watch_count += 1
            if self.continuous is not None:
                self.continuous.append(group)
                if len(self.continuous) >= RECORDING_MAX_GROUPS:
                    log.warning("continuous recording stopped: %d groups", len(self.continuous))
                    self.segments.append(self.continuous)
                    self.continuous = None
            self.new_group.notify_all()

    def _raw_raw(self, inp: Any, sample: Any) -> tuple[float, float, float]:
        return sample.value, inp.min_system_cutoff, inp.max_system_cutoff

    def _check_range(self, inp: Any, sample: Any) -> None:
        value, lo_sys, hi_sys = self._raw_raw(inp, sample)
        out = (inp.has_max_user_cutoff and value > inp.max_user_cutoff) or (
            inp.has_min_user_cutoff and value < inp.min_user_cutoff
        )
        if hi_sys > lo_sys and not lo_sys <= value <= hi_sys:
            out = True
        if out:
            fs = self.fs
            cond = fs.CutoffCondition(type=fs.OUT_OF_RANGE_SIGNAL)
            cond.cutoff_trigger_sample.CopyFrom(sample)
            cond.cutoff_trigger_signal.CopyFrom(fs.Signal(name=inp.signal_name))
            self.trigger_cutoff(cond, f"{inp.display_name} {value:.3f} out of range")

    def conditions_holding(self) -> list[Any]:
        """The cutoff conditions that hold now (a cutoff cannot be cleared while one does)."""
        fs = self.fs
        out = []
        with self.lock:
            latest = {s.signal_name: s for s in self.history[-1].samples} if self.history else {}
            for board in self.boards.values():
                for inp in board.inputs.values():
                    sample = latest.get(inp.signal_name)
                    if sample is None:
                        continue
                    v = sample.value
                    if (inp.has_max_user_cutoff and v > inp.max_user_cutoff) or (
                        inp.has_min_user_cutoff and v < inp.min_user_cutoff
                    ):
                        cond = fs.CutoffCondition(type=fs.OUT_OF_RANGE_SIGNAL)
                        cond.cutoff_trigger_sample.CopyFrom(sample)
                        cond.cutoff_trigger_signal.CopyFrom(fs.Signal(name=inp.signal_name))
                        out.append(cond)
        return out

    def trigger_cutoff(self, condition: Any, why: str) -> None:
        """Every ESC output goes to its cutoff target now; outputs stay there until cleared."""
        with self.lock:
            if self.cutoff is None:
                self.cutoff = condition
                log.warning("simulated Flight Stand core: CUTOFF (%s)", why)
            now = time.monotonic()
            for board in self.boards.values():
                board.esc.output_target.CopyFrom(board.esc.cutoff_target)
                board.esc_active = board.esc.output_target.active
                board.esc_value_us = board.esc.output_target.target_value
                board.esc_changed_wall_s = time.time()
                self._apply_esc(board, now)

    def heartbeat(self) -> None:
        now = time.monotonic()
        with self.lock:
            if self.last_poll_s is not None and now - self.last_poll_s < self.no_client_timeout_s:
                self.heartbeating = True
            self.last_poll_s = now

    def _check_heartbeat(self, now_s: float) -> None:
        if not self.heartbeating or self.last_poll_s is None:
            return
        if now_s - self.last_poll_s <= self.no_client_timeout_s:
            return
        self.heartbeating = False  # the heartbeating client is gone
        if any(b.esc.output_target.active for b in self.boards.values()):
            fs = self.fs
            self.trigger_cutoff(
                fs.CutoffCondition(type=fs.NO_CLIENT),
                f"no heartbeat for {now_s - self.last_poll_s:.2f} s",
            )

    def tare(self, window_s: float = 0.3) -> None:
        """Zero the tared inputs on the mean of their last ``window_s`` of raw readings."""
        with self.lock:
            groups = list(self.history)[-max(1, round(window_s / self.period_s)) :]
            for board in self.boards.values():
                for inp in board.inputs.values():
                    if not inp.has_tare:
                        continue
                    values = [s.value + inp.tare_offset for g in groups for s in g.samples
                              if s.signal_name == inp.signal_name]  # fmt: skip
                    if values:
                        inp.tare_offset = math.fsum(values) / len(values)

    # -- the test recorder --------------------------------------------------------------------
    def take_manual_sample(self) -> bool:
        with self.lock:
            now = time.monotonic()
            if now - self._last_manual_s < 0.05 or not self.history:
                return False
            self._last_manual_s = now
            self.manual.append(self.history[-1])
            return True

    def set_recording(self, on: bool) -> None:
        with self.lock:
            if on and self.continuous is None:
                self.continuous = []
            elif not on and self.continuous is not None:
                self.segments.append(self.continuous)
                self.continuous = None

    def clear_recorder(self) -> None:
        with self.lock:
            self.manual, self.segments, self.recorder_title = [], [], ""
            self.continuous = [] if self.continuous is not None else None

    def save(self) -> str:
        with self.lock:
            self.set_recording(False)
            name = f"/tests/{len(self.tests) + 1}"
            self.tests[name] = (self.recorder_title, self.manual, self.segments)
            self.manual, self.segments, self.recorder_title = [], [], ""
            return name


def _timestamp(fs: Any, wall_s: float) -> Any:
    from google.protobuf.timestamp_pb2 import Timestamp

    ts = Timestamp()
    seconds = math.floor(wall_s)
    ts.seconds, ts.nanos = seconds, int((wall_s - seconds) * 1e9)
    return ts


def seconds_of(ts: Any) -> float:
    """A protobuf ``Timestamp`` in seconds."""
    return float(ts.seconds) + float(ts.nanos) * 1e-9


def resample(groups: list[Any], step_s: float, fs: Any) -> list[Any]:
    """Linear interpolation of each signal onto a regular grid ``step_s`` apart."""
    if step_s <= 0 or len(groups) < 2:
        return list(groups)
    times = [seconds_of(g.group_time) for g in groups]
    out: list[Any] = []
    j = 0
    t = times[0]
    while t <= times[-1] and len(out) < 2_000_000:
        while j + 1 < len(times) - 1 and times[j + 1] < t:
            j += 1
        t0, t1 = times[j], times[j + 1]
        f = 0.0 if t1 <= t0 else min(max((t - t0) / (t1 - t0), 0.0), 1.0)
        stamp = _timestamp(fs, t)
        samples = []
        for a, b in zip(groups[j].samples, groups[j + 1].samples, strict=False):
            s = fs.Sample(signal_name=a.signal_name, active=a.active,
                          value=a.value + f * (b.value - a.value),
                          filtered_value=a.filtered_value + f * (b.filtered_value - a.filtered_value))  # fmt: skip
            s.sample_time.CopyFrom(stamp)
            samples.append(s)
        group = fs.SampleGroup(samples=samples)
        group.group_time.CopyFrom(stamp)
        out.append(group)
        t += step_s
    return out
