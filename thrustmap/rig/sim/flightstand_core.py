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
"""

from __future__ import annotations

import functools
import logging
import math
import os
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from concurrent import futures
from dataclasses import dataclass, field
from typing import Any, NoReturn

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
class _Board:
    name: str
    display_name: str
    serial: str
    plant: PhysicsPlant
    inputs: dict[str, Any] = field(default_factory=dict)  # input id -> fs.Input
    esc: Any = None  # fs.Output
    esc_value_us: float = PWM_STOP_US
    esc_active: bool = False
    esc_changed_wall_s: float = 0.0


def _signal_id(board: _Board, name: str) -> str:
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
        self.boards: dict[str, _Board] = {}
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
    def add_board(self) -> _Board:
        fs = self.fs
        with self.lock:
            self._board_serial += 1
            n = self._board_serial
            plant = make_plant(self.plant_name, rotors_on_esc=1, seed=self.seed + n - 1,
                               noise=self.noise)  # fmt: skip
            board = _Board(f"/boards/simulated_{n}", f"Flight Stand 50 (simulated {n})",
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

    def board_message(self, board: _Board) -> Any:
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

    def _apply_esc(self, board: _Board, now_s: float) -> None:
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


def _seconds(ts: Any) -> float:
    return float(ts.seconds) + float(ts.nanos) * 1e-9


def resample(groups: list[Any], step_s: float, fs: Any) -> list[Any]:
    """Linear interpolation of each signal onto a regular grid ``step_s`` apart."""
    if step_s <= 0 or len(groups) < 2:
        return list(groups)
    times = [_seconds(g.group_time) for g in groups]
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


def make_servicer(core: FlightStandCore) -> Any:
    """The gRPC servicer: the package's ``FlightStandServicer`` with the calls implemented."""
    import grpc
    from FlightStand import flight_stand_api_v1_pb2_grpc as fs_grpc

    fs = core.fs

    def abort(context: Any, code: Any, message: str) -> NoReturn:
        context.abort(code, message)  # raises
        raise AssertionError("unreachable")

    def board_of(context: Any, name: str) -> _Board:
        board = core.boards.get(name)
        if board is None:
            abort(context, grpc.StatusCode.NOT_FOUND, f"no board {name!r}")
        return board

    class Servicer(fs_grpc.FlightStandServicer):  # type: ignore[misc]
        def GetServerStatus(self, request: Any, context: Any) -> Any:  # noqa: N802
            core.heartbeat()
            return fs.ServerStatus()

        def GetCore(self, request: Any, context: Any) -> Any:  # noqa: N802
            with core.lock:
                msg = fs.Core(autoconnect_com_ports=True, autosync_timestamps=True)
                if core.cutoff is not None:
                    msg.cutoff_active.CopyFrom(core.cutoff)
                return msg

        def ListBoards(self, request: Any, context: Any) -> Any:  # noqa: N802
            with core.lock:
                return fs.ListBoardsResponse(
                    boards=[core.board_message(b) for b in core.boards.values()]
                )

        def GetBoard(self, request: Any, context: Any) -> Any:  # noqa: N802
            with core.lock:
                return core.board_message(board_of(context, request.name))

        def CreateSimulatedBoard(self, request: Any, context: Any) -> Any:  # noqa: N802
            core.add_board()
            return fs.CreateSimulatedBoardResponse()

        def DisconnectBoard(self, request: Any, context: Any) -> Any:  # noqa: N802
            with core.lock:
                board = board_of(context, request.board_name)
                board.esc.output_target.CopyFrom(board.esc.cutoff_target)
                del core.boards[board.name]
            return fs.DisconnectBoardResponse()

        def ListInputs(self, request: Any, context: Any) -> Any:  # noqa: N802
            with core.lock:
                return fs.ListInputsResponse(
                    inputs=[i for b in core.boards.values() for i in b.inputs.values()]
                )

        def GetInput(self, request: Any, context: Any) -> Any:  # noqa: N802
            with core.lock:
                for b in core.boards.values():
                    for i in b.inputs.values():
                        if i.name == request.name:
                            return i
            abort(context, grpc.StatusCode.NOT_FOUND, f"no input {request.name!r}")

        def UpdateInput(self, request: Any, context: Any) -> Any:  # noqa: N802
            allowed = {"alias", "reversed", "min_user_cutoff", "max_user_cutoff",
                       "has_min_user_cutoff", "has_max_user_cutoff", "enabled"}  # fmt: skip
            paths = list(request.mask.paths)
            bad = [p for p in paths if p not in allowed]
            if bad or not paths:
                abort(context, grpc.StatusCode.INVALID_ARGUMENT,
                              f"mask paths {bad or paths} cannot be updated")  # fmt: skip
            with core.lock:
                for b in core.boards.values():
                    for i in b.inputs.values():
                        if i.name == request.input.name:
                            for p in paths:
                                setattr(i, p, getattr(request.input, p))
                            return i
            abort(context, grpc.StatusCode.NOT_FOUND, f"no input {request.input.name!r}")

        def ListOutputs(self, request: Any, context: Any) -> Any:  # noqa: N802
            with core.lock:
                return fs.ListOutputsResponse(outputs=[b.esc for b in core.boards.values()])

        def GetOutput(self, request: Any, context: Any) -> Any:  # noqa: N802
            with core.lock:
                for b in core.boards.values():
                    if b.esc.name == request.name:
                        return b.esc
            abort(context, grpc.StatusCode.NOT_FOUND, f"no output {request.name!r}")

        def UpdateOutput(self, request: Any, context: Any) -> Any:  # noqa: N802
            paths = list(request.mask.paths)
            if paths != ["output_target"]:
                abort(context, grpc.StatusCode.INVALID_ARGUMENT,
                              f"this simulated core updates output_target only, not {paths}")  # fmt: skip
            with core.lock:
                board = next((b for b in core.boards.values() if b.esc.name == request.output.name),
                             None)  # fmt: skip
                if board is None:
                    abort(context, grpc.StatusCode.NOT_FOUND, f"no output {request.output.name!r}")
                target = request.output.output_target
                esc = board.esc
                if target.active and not (
                    esc.min_user_value <= target.target_value <= esc.max_user_value
                ):
                    context.abort(
                        grpc.StatusCode.INVALID_ARGUMENT,
                        f"output target {target.target_value:g} outside the user range "
                        f"[{esc.min_user_value:g}, {esc.max_user_value:g}]",
                    )
                if core.cutoff is not None and (
                    target.active != esc.cutoff_target.active
                    or target.target_value != esc.cutoff_target.target_value
                ):
                    abort(context, grpc.StatusCode.FAILED_PRECONDITION,
                                  "a cutoff is active: clear it before changing an output")  # fmt: skip
                esc.output_target.CopyFrom(target)
                esc.output_target.target_value = round(target.target_value / esc.step_size) * (
                    esc.step_size
                )
                return esc

        def ListSamples(self, request: Any, context: Any) -> Any:  # noqa: N802
            with core.lock:
                group = core.history[-1] if core.history else fs.SampleGroup()
                return fs.ListSamplesResponse(sample_group=group)

        def WatchSamples(self, requests: Any, context: Any) -> Iterator[Any]:  # noqa: N802
            """As the service documents it: a bidirectional stream at a fixed 10 Hz, one
            response per request (the client acknowledges each), the groups taken since the last
            response buffered up to ``WATCH_BUFFER_GROUPS``."""
            with core.lock:
                if core.watchers >= MAX_WATCHERS:
                    abort(context, grpc.StatusCode.RESOURCE_EXHAUSTED,
                          f"at most {MAX_WATCHERS} sample watchers")  # fmt: skip
                core.watchers += 1
                seen = core.watch_count
            try:
                for _ in requests:
                    groups: list[Any] = []
                    while not groups and context.is_active() and not core.closed:
                        with core.new_group:
                            core.new_group.wait_for(
                                functools.partial(core.has_news, seen), timeout=0.5
                            )
                            fresh = min(core.watch_count - seen, len(core.watch_history))
                            if fresh:
                                groups = list(core.watch_history)[-fresh:]
                            seen = core.watch_count
                    if not groups:
                        return
                    yield fs.WatchSamplesResponse(sample_groups=groups)
            finally:
                with core.lock:
                    core.watchers -= 1

        def ListSignalStats(self, request: Any, context: Any) -> Any:  # noqa: N802
            with core.lock:
                names = [s.signal_name for s in core.history[-1].samples] if core.history else []
            rate = 1.0 / core.period_s
            return fs.ListSignalStatsResponse(
                signal_stats=[fs.SignalStat(signal_name=n, update_rate_hz=rate) for n in names]
            )

        def TareInputs(self, request: Any, context: Any) -> Any:  # noqa: N802
            core.tare()
            return fs.TareInputsResponse()

        def TriggerCutoff(self, request: Any, context: Any) -> Any:  # noqa: N802
            core.trigger_cutoff(fs.CutoffCondition(type=fs.MANUAL), "TriggerCutoff")
            return fs.TriggerCutoffResponse()

        def ClearCutoff(self, request: Any, context: Any) -> Any:  # noqa: N802
            holding = core.conditions_holding()
            with core.lock:
                if core.cutoff is None:
                    return fs.ClearCutoffResponse()
                if holding:
                    abort(context, grpc.StatusCode.FAILED_PRECONDITION,
                                  "a cutoff condition still holds")  # fmt: skip
                core.cutoff = None
                log.info("simulated Flight Stand core: cutoff cleared")
            return fs.ClearCutoffResponse()

        def ListCutoffConditions(self, request: Any, context: Any) -> Any:  # noqa: N802
            return fs.ListCutoffConditionsResponse(cutoff_conditions=core.conditions_holding())

        def TakeSampleTestRecorder(self, request: Any, context: Any) -> Any:  # noqa: N802
            if not core.take_manual_sample():
                abort(
                    context, grpc.StatusCode.RESOURCE_EXHAUSTED, "manual samples are rate limited"
                )
            return fs.TakeSampleTestRecorderResponse()

        def ClearTestRecorder(self, request: Any, context: Any) -> Any:  # noqa: N802
            core.clear_recorder()
            return fs.ClearTestRecorderResponse()

        def GetTestRecorder(self, request: Any, context: Any) -> Any:  # noqa: N802
            with core.lock:
                return fs.TestRecorder(
                    is_continuous_recording=core.continuous is not None,
                    title=core.recorder_title,
                    manual_samples_count=len(core.manual),
                )

        def UpdateTestRecorder(self, request: Any, context: Any) -> Any:  # noqa: N802
            for path in request.mask.paths:
                if path == "is_continuous_recording":
                    core.set_recording(request.test_recorder.is_continuous_recording)
                elif path == "title":
                    with core.lock:
                        core.recorder_title = request.test_recorder.title
                else:
                    abort(context, grpc.StatusCode.INVALID_ARGUMENT, f"cannot update {path!r}")
            return self.GetTestRecorder(fs.GetTestRecorderRequest(), context)

        def SaveTestRecorder(self, request: Any, context: Any) -> Any:  # noqa: N802
            with core.lock:
                if not core.recorder_title:
                    abort(context, grpc.StatusCode.FAILED_PRECONDITION, "a test needs a title")
                return fs.SaveTestRecorderResponse(test_name=core.save())

        def ListTestData(self, request: Any, context: Any) -> Any:  # noqa: N802
            with core.lock:
                test = core.tests.get(request.test_name)
            if test is None:
                abort(context, grpc.StatusCode.NOT_FOUND, f"no test {request.test_name!r}")
            _, manual, segments = test
            if request.continuous_recording:
                if not 0 <= request.continuous_segment_index < len(segments):
                    abort(context, grpc.StatusCode.OUT_OF_RANGE, "no such continuous segment")
                step = _seconds(request.resample_step_duration)
                rows = resample(segments[request.continuous_segment_index], step, fs)
            else:
                rows = manual
            size = request.page_size if request.page_size > 0 else 1000
            start = int(request.page_token) if request.page_token.isdigit() else 0
            end = min(start + size, len(rows))
            token = str(end) if end < len(rows) else ""
            return fs.ListTestSamplesResponse(
                sample_groups=rows[start:end], next_page_token=token, progress=100.0,
                rows_count=len(rows),
            )  # fmt: skip

    return Servicer()


class FlightStandServer:
    """The simulated core served over gRPC on ``host:port`` (loopback unless told otherwise)."""

    def __init__(self, core: FlightStandCore, *, host: str = "127.0.0.1", port: int = 0) -> None:
        import grpc
        from FlightStand import flight_stand_api_v1_pb2_grpc as fs_grpc

        self.core = core
        # every watcher holds a worker; the examples and thrustmap need a few more
        # no SO_REUSEPORT: a second core on a port in use must fail, not share it silently
        self.server = grpc.server(
            futures.ThreadPoolExecutor(max_workers=MAX_WATCHERS + 8),
            options=[("grpc.so_reuseport", 0)],
        )
        fs_grpc.add_FlightStandServicer_to_server(make_servicer(core), self.server)
        where = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
        try:
            self.port = self.server.add_insecure_port(where)
        except RuntimeError as exc:
            raise ConfigError(f"cannot listen on {where}: {exc}") from None
        if self.port == 0:
            raise ConfigError(f"cannot listen on {where} (in use, or not an address here)")
        self.host = host

    @property
    def address(self) -> str:
        return f"{self.host}:{self.port}"

    def start(self) -> FlightStandServer:
        self.core.start()
        self.server.start()
        log.info("simulated Flight Stand core on %s", self.address)
        return self

    def stop(self, grace_s: float | None = None) -> None:
        self.core.close()
        self.server.stop(grace_s).wait(5.0)

    def __enter__(self) -> FlightStandServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def serve(
    *,
    host: str = "127.0.0.1",
    port: int = DEFAULT_PORT,
    ready: Callable[[FlightStandServer], None] | None = None,
    duration_s: float | None = None,
    **core_options: Any,
) -> None:
    """Serve a simulated core until Ctrl-C/SIGTERM (or ``duration_s``)."""
    from thrustmap.rig.safety import terminate_as_exception

    with terminate_as_exception(), FlightStandServer(FlightStandCore(**core_options),
                                                     host=host, port=port) as server:  # fmt: skip
        if ready is not None:
            ready(server)
        deadline = None if duration_s is None else time.monotonic() + duration_s
        try:
            while deadline is None or time.monotonic() < deadline:
                time.sleep(0.2)
        except KeyboardInterrupt:
            log.info("simulated Flight Stand core stopping")
