"""The simulated Flight Stand core served over gRPC: the official package's
``FlightStandServicer`` with every call thrustmap and Tyto's example scripts make implemented
on a ``FlightStandCore`` (``rig.sim.flightstand_core``: boards, physics, cutoffs, recorder),
the server on loopback (``FlightStandServer``), and ``serve`` for ``thrustmap sim-serve``.
"""

from __future__ import annotations

import functools
import logging
import time
from collections.abc import Callable, Iterator
from concurrent import futures
from typing import Any, NoReturn

from thrustmap.core.errors import ConfigError
from thrustmap.rig.sim.flightstand_core import (
    DEFAULT_PORT,
    MAX_WATCHERS,
    Board,
    FlightStandCore,
    resample,
    seconds_of,
)

log = logging.getLogger(__name__)


class FlightStandCalls:
    """Every call of the Flight Stand service implemented on a ``FlightStandCore``: the
    servicer's methods (``make_servicer`` puts them on the package's ``FlightStandServicer``).
    """

    def __init__(self, core: FlightStandCore) -> None:
        import grpc

        self.core = core
        self.fs = core.fs
        self.codes = grpc.StatusCode

    def _abort(self, context: Any, code: Any, message: str) -> NoReturn:
        context.abort(code, message)  # raises
        raise AssertionError("unreachable")

    def _board_of(self, context: Any, name: str) -> Board:
        board = self.core.boards.get(name)
        if board is None:
            self._abort(context, self.codes.NOT_FOUND, f"no board {name!r}")
        return board

    def GetServerStatus(self, request: Any, context: Any) -> Any:  # noqa: N802
        self.core.heartbeat()
        return self.fs.ServerStatus()

    def GetCore(self, request: Any, context: Any) -> Any:  # noqa: N802
        with self.core.lock:
            msg = self.fs.Core(autoconnect_com_ports=True, autosync_timestamps=True)
            if self.core.cutoff is not None:
                msg.cutoff_active.CopyFrom(self.core.cutoff)
            return msg

    def ListBoards(self, request: Any, context: Any) -> Any:  # noqa: N802
        with self.core.lock:
            return self.fs.ListBoardsResponse(
                boards=[self.core.board_message(b) for b in self.core.boards.values()]
            )

    def GetBoard(self, request: Any, context: Any) -> Any:  # noqa: N802
        with self.core.lock:
            return self.core.board_message(self._board_of(context, request.name))

    def CreateSimulatedBoard(self, request: Any, context: Any) -> Any:  # noqa: N802
        self.core.add_board()
        return self.fs.CreateSimulatedBoardResponse()

    def DisconnectBoard(self, request: Any, context: Any) -> Any:  # noqa: N802
        with self.core.lock:
            board = self._board_of(context, request.board_name)
            board.esc.output_target.CopyFrom(board.esc.cutoff_target)
            del self.core.boards[board.name]
        return self.fs.DisconnectBoardResponse()

    def ListInputs(self, request: Any, context: Any) -> Any:  # noqa: N802
        with self.core.lock:
            return self.fs.ListInputsResponse(
                inputs=[i for b in self.core.boards.values() for i in b.inputs.values()]
            )

    def GetInput(self, request: Any, context: Any) -> Any:  # noqa: N802
        with self.core.lock:
            for b in self.core.boards.values():
                for i in b.inputs.values():
                    if i.name == request.name:
                        return i
        self._abort(context, self.codes.NOT_FOUND, f"no input {request.name!r}")

    def UpdateInput(self, request: Any, context: Any) -> Any:  # noqa: N802
        allowed = {"alias", "reversed", "min_user_cutoff", "max_user_cutoff",
                   "has_min_user_cutoff", "has_max_user_cutoff", "enabled"}  # fmt: skip
        paths = list(request.mask.paths)
        bad = [p for p in paths if p not in allowed]
        if bad or not paths:
            self._abort(context, self.codes.INVALID_ARGUMENT,
                          f"mask paths {bad or paths} cannot be updated")  # fmt: skip
        with self.core.lock:
            for b in self.core.boards.values():
                for i in b.inputs.values():
                    if i.name == request.input.name:
                        for p in paths:
                            setattr(i, p, getattr(request.input, p))
                        return i
        self._abort(context, self.codes.NOT_FOUND, f"no input {request.input.name!r}")

    def ListOutputs(self, request: Any, context: Any) -> Any:  # noqa: N802
        with self.core.lock:
            return self.fs.ListOutputsResponse(outputs=[b.esc for b in self.core.boards.values()])

    def GetOutput(self, request: Any, context: Any) -> Any:  # noqa: N802
        with self.core.lock:
            for b in self.core.boards.values():
                if b.esc.name == request.name:
                    return b.esc
        self._abort(context, self.codes.NOT_FOUND, f"no output {request.name!r}")

    def UpdateOutput(self, request: Any, context: Any) -> Any:  # noqa: N802
        paths = list(request.mask.paths)
        if paths != ["output_target"]:
            self._abort(context, self.codes.INVALID_ARGUMENT,
                          f"this simulated core updates output_target only, not {paths}")  # fmt: skip
        with self.core.lock:
            board = next((b for b in self.core.boards.values() if b.esc.name == request.output.name),
                         None)  # fmt: skip
            if board is None:
                self._abort(context, self.codes.NOT_FOUND, f"no output {request.output.name!r}")
            target = request.output.output_target
            esc = board.esc
            if target.active and not (
                esc.min_user_value <= target.target_value <= esc.max_user_value
            ):
                context.abort(
                    self.codes.INVALID_ARGUMENT,
                    f"output target {target.target_value:g} outside the user range "
                    f"[{esc.min_user_value:g}, {esc.max_user_value:g}]",
                )
            if self.core.cutoff is not None and (
                target.active != esc.cutoff_target.active
                or target.target_value != esc.cutoff_target.target_value
            ):
                self._abort(context, self.codes.FAILED_PRECONDITION,
                              "a cutoff is active: clear it before changing an output")  # fmt: skip
            esc.output_target.CopyFrom(target)
            esc.output_target.target_value = round(target.target_value / esc.step_size) * (
                esc.step_size
            )
            return esc

    def ListSamples(self, request: Any, context: Any) -> Any:  # noqa: N802
        with self.core.lock:
            group = self.core.history[-1] if self.core.history else self.fs.SampleGroup()
            return self.fs.ListSamplesResponse(sample_group=group)

    def WatchSamples(self, requests: Any, context: Any) -> Iterator[Any]:  # noqa: N802
        """As the service documents it: a bidirectional stream at a fixed 10 Hz, one
        response per request (the client acknowledges each), the groups taken since the last
        response buffered up to ``WATCH_BUFFER_GROUPS``."""
        with self.core.lock:
            if self.core.watchers >= MAX_WATCHERS:
                self._abort(context, self.codes.RESOURCE_EXHAUSTED,
                      f"at most {MAX_WATCHERS} sample watchers")  # fmt: skip
            self.core.watchers += 1
            seen = self.core.watch_count
        try:
            for _ in requests:
                groups: list[Any] = []
                while not groups and context.is_active() and not self.core.closed:
                    with self.core.new_group:
                        self.core.new_group.wait_for(
                            functools.partial(self.core.has_news, seen), timeout=0.5
                        )
                        fresh = min(self.core.watch_count - seen, len(self.core.watch_history))
                        if fresh:
                            groups = list(self.core.watch_history)[-fresh:]
                        seen = self.core.watch_count
                if not groups:
                    return
                yield self.fs.WatchSamplesResponse(sample_groups=groups)
        finally:
            with self.core.lock:
                self.core.watchers -= 1

    def ListSignalStats(self, request: Any, context: Any) -> Any:  # noqa: N802
        with self.core.lock:
            names = (
                [s.signal_name for s in self.core.history[-1].samples] if self.core.history else []
            )
        rate = 1.0 / self.core.period_s
        return self.fs.ListSignalStatsResponse(
            signal_stats=[self.fs.SignalStat(signal_name=n, update_rate_hz=rate) for n in names]
        )

    def TareInputs(self, request: Any, context: Any) -> Any:  # noqa: N802
        self.core.tare()
        return self.fs.TareInputsResponse()

    def TriggerCutoff(self, request: Any, context: Any) -> Any:  # noqa: N802
        self.core.trigger_cutoff(self.fs.CutoffCondition(type=self.fs.MANUAL), "TriggerCutoff")
        return self.fs.TriggerCutoffResponse()

    def ClearCutoff(self, request: Any, context: Any) -> Any:  # noqa: N802
        holding = self.core.conditions_holding()
        with self.core.lock:
            if self.core.cutoff is None:
                return self.fs.ClearCutoffResponse()
            if holding:
                self._abort(context, self.codes.FAILED_PRECONDITION,
                              "a cutoff condition still holds")  # fmt: skip
            self.core.cutoff = None
            log.info("simulated Flight Stand core: cutoff cleared")
        return self.fs.ClearCutoffResponse()

    def ListCutoffConditions(self, request: Any, context: Any) -> Any:  # noqa: N802
        return self.fs.ListCutoffConditionsResponse(
            cutoff_conditions=self.core.conditions_holding()
        )

    def TakeSampleTestRecorder(self, request: Any, context: Any) -> Any:  # noqa: N802
        if not self.core.take_manual_sample():
            self._abort(context, self.codes.RESOURCE_EXHAUSTED, "manual samples are rate limited")
        return self.fs.TakeSampleTestRecorderResponse()

    def ClearTestRecorder(self, request: Any, context: Any) -> Any:  # noqa: N802
        self.core.clear_recorder()
        return self.fs.ClearTestRecorderResponse()

    def GetTestRecorder(self, request: Any, context: Any) -> Any:  # noqa: N802
        with self.core.lock:
            return self.fs.TestRecorder(
                is_continuous_recording=self.core.continuous is not None,
                title=self.core.recorder_title,
                manual_samples_count=len(self.core.manual),
            )

    def UpdateTestRecorder(self, request: Any, context: Any) -> Any:  # noqa: N802
        for path in request.mask.paths:
            if path == "is_continuous_recording":
                self.core.set_recording(request.test_recorder.is_continuous_recording)
            elif path == "title":
                with self.core.lock:
                    self.core.recorder_title = request.test_recorder.title
            else:
                self._abort(context, self.codes.INVALID_ARGUMENT, f"cannot update {path!r}")
        return self.GetTestRecorder(self.fs.GetTestRecorderRequest(), context)

    def SaveTestRecorder(self, request: Any, context: Any) -> Any:  # noqa: N802
        with self.core.lock:
            if not self.core.recorder_title:
                self._abort(context, self.codes.FAILED_PRECONDITION, "a test needs a title")
            return self.fs.SaveTestRecorderResponse(test_name=self.core.save())

    def ListTestData(self, request: Any, context: Any) -> Any:  # noqa: N802
        with self.core.lock:
            test = self.core.tests.get(request.test_name)
        if test is None:
            self._abort(context, self.codes.NOT_FOUND, f"no test {request.test_name!r}")
        _, manual, segments = test
        if request.continuous_recording:
            if not 0 <= request.continuous_segment_index < len(segments):
                self._abort(context, self.codes.OUT_OF_RANGE, "no such continuous segment")
            step = seconds_of(request.resample_step_duration)
            rows = resample(segments[request.continuous_segment_index], step, self.fs)
        else:
            rows = manual
        size = request.page_size if request.page_size > 0 else 1000
        start = int(request.page_token) if request.page_token.isdigit() else 0
        end = min(start + size, len(rows))
        token = str(end) if end < len(rows) else ""
        return self.fs.ListTestSamplesResponse(
            sample_groups=rows[start:end], next_page_token=token, progress=100.0,
            rows_count=len(rows),
        )  # fmt: skip


def make_servicer(core: FlightStandCore) -> Any:
    """The gRPC servicer: the package's ``FlightStandServicer`` with the calls implemented."""
    from FlightStand import flight_stand_api_v1_pb2_grpc as fs_grpc

    class Servicer(FlightStandCalls, fs_grpc.FlightStandServicer):  # type: ignore[misc]
        pass

    return Servicer(core)


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
    from thrustmap.rig.sigterm import terminate_as_exception

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
