"""Listening to a flying vehicle's MAVLink telemetry: a live link, or a .tlog replayed.

Both sources yield ``(time_s, message)`` in arrival order: a live link stamps each message with
the wall-clock receive time rounded to the microsecond (what a .tlog record stores), a replay
with the time the recording stored, so a recording replays to exactly the numbers of the live
run. A live link writes every decoded message to ``record`` as it arrives (8-byte big-endian µs
+ the frame as received: a .tlog that `flightlog extract` and `gamma live replay://` both read).

What a live link sends to the vehicle, and nothing else (no command can arm, move or change it):
- MAV_CMD_SET_MESSAGE_INTERVAL for the messages a Df needs. The autopilot applies it to this
  link and does not save it. REQUEST_DATA_STREAM is never sent: ArduPilot saves that request
  into its SRn_ parameters (``set_and_save_ifchanged``), which would change the vehicle.
- PARAM_REQUEST_READ for the few parameters that scale the motor outputs and name the frame.
It never sends a HEARTBEAT, so it stays invisible to failsafes that watch for a ground station,
and it can listen on a ground station's forwarded stream (then its requests go to whoever sent
the stream, or nowhere; what does not arrive is named).
"""

from __future__ import annotations

import logging
import struct
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

from thrustmap.core.errors import ConfigError, DataFormatError

log = logging.getLogger(__name__)

MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_RESULT_NAMES = {
    0: "accepted",
    1: "temporarily rejected",
    2: "denied",
    3: "unsupported",
    4: "failed",
    5: "in progress",
    6: "cancelled",
}
#: message -> (id, rate Hz) asked for; the IMU at a rate the Df's vibration rule accepts (20+ Hz)
RATES_COMMON: dict[str, tuple[int, float]] = {
    "SYS_STATUS": (1, 5.0),
    "EXTENDED_SYS_STATE": (245, 5.0),
    "SERVO_OUTPUT_RAW": (36, 25.0),
    "ATTITUDE": (30, 25.0),
    "VFR_HUD": (74, 10.0),
    "GLOBAL_POSITION_INT": (33, 10.0),
}
RATES_PX4: dict[str, tuple[int, float]] = {
    "HIGHRES_IMU": (105, 50.0),
    "ATTITUDE_TARGET": (83, 25.0),
}
RATES_ARDUPILOT: dict[str, tuple[int, float]] = {"RAW_IMU": (27, 50.0)}
PARAMS_ARDUPILOT = (
    "FRAME_CLASS",
    "FRAME_TYPE",
    "MOT_PWM_MIN",
    "MOT_PWM_MAX",
    "MOT_SPIN_MIN",
    "MOT_SPIN_MAX",
    "MOT_THST_HOVER",
)
PARAMS_PX4 = ("MPC_THR_HOVER", "CA_ROTOR_COUNT", "PWM_MAIN_MIN1", "PWM_MAIN_MAX1")
MAV_AUTOPILOT_ARDUPILOTMEGA, MAV_AUTOPILOT_PX4 = 3, 12
#: the requests not yet answered by a message are sent once more after this (s)
RETRY_AFTER_S = 3.0


def rates_for(autopilot: int) -> dict[str, tuple[int, float]]:
    extra = RATES_ARDUPILOT if autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA else RATES_PX4
    return {**RATES_COMMON, **extra}


def params_for(autopilot: int) -> tuple[str, ...]:
    return PARAMS_ARDUPILOT if autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA else PARAMS_PX4


class LinkLost(Exception):
    """No message from the vehicle for the link timeout."""


@dataclass
class RateRequests:
    """What was asked of the vehicle and how it answered (per message name)."""

    asked: dict[str, float] = field(default_factory=dict)  # name -> Hz
    answers: dict[str, str] = field(default_factory=dict)  # name -> result name
    params: tuple[str, ...] = ()

    def refused(self) -> dict[str, str]:
        return {k: v for k, v in self.answers.items() if v != "accepted"}


class TlogWriter:
    """Appends (µs, frame) records; refuses to replace a file (a recording is never lost)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        try:
            self._f: BinaryIO | None = open(path, "xb")  # noqa: SIM115 - closed in close()
        except FileExistsError:
            raise ConfigError(
                "recording exists; choose a new name (a recording is never overwritten)",
                file=str(path),
            ) from None
        except OSError as exc:
            raise ConfigError(
                f"cannot create the recording ({exc.strerror})", file=str(path)
            ) from None
        self.records = 0

    def write(self, t_us: int, frame: bytes) -> None:
        if self._f is None:
            return
        self._f.write(struct.pack(">Q", t_us) + frame)
        self.records += 1
        if self.records % 200 == 0:
            self._f.flush()

    def close(self) -> None:
        if self._f is not None:
            self._f.flush()
            self._f.close()
            self._f = None


def wall_clock_us() -> int:
    return time.time_ns() // 1000


class LiveStream:
    """A live MAVLink link (any URL ``open_mavlink`` takes) as ``(time_s, message)`` pairs.

    ``messages()`` yields until ``stop()`` is called; it raises ``LinkLost`` when the vehicle
    has been heard and then nothing came from it for ``link_timeout_s`` (wall time), and when
    no vehicle is heard within ``start_timeout_s``. Times come from ``clock_us`` (wall µs).
    """

    def __init__(
        self,
        url: str,
        *,
        record: Path | None = None,
        link_timeout_s: float = 5.0,
        start_timeout_s: float = 30.0,
        clock_us: Callable[[], int] = wall_clock_us,
        poll_s: float = 0.1,
        signing_key: Any = None,
    ) -> None:
        from thrustmap.protocols.mavlink.link import open_mavlink

        self.url = url
        self.link_timeout_s = link_timeout_s
        self.start_timeout_s = start_timeout_s
        self.clock_us = clock_us
        self.poll_s = poll_s
        self.requests = RateRequests()
        self.recorder = TlogWriter(record) if record is not None else None
        try:
            self.link = open_mavlink(url)
        except Exception as exc:
            if self.recorder is not None:
                self.recorder.close()
                if self.recorder.records == 0:
                    self.recorder.path.unlink(missing_ok=True)
            raise ConfigError(f"cannot open {url}: {exc}") from None
        if signing_key is not None:  # sign the rate requests, refuse unsigned messages
            from thrustmap.protocols.mavlink.signing import enable_signing

            enable_signing(self.link, signing_key)
        self._stopped = False
        self._vehicle: tuple[int, int, int] | None = None  # system, component, autopilot
        self._seen: set[str] = set()  # message types heard from the vehicle
        self._param_names: set[str] = set()  # parameters heard from the vehicle
        self._pending: dict[int, str] = {}  # SET_MESSAGE_INTERVAL not acknowledged yet
        self._asked_at_us: int | None = None
        self._retried = False
        self.bad_bytes = 0

    def stop(self) -> None:
        self._stopped = True

    def close(self) -> None:
        try:
            self.link.close()
        finally:
            if self.recorder is not None:
                self.recorder.close()

    def messages(self) -> Iterator[tuple[float, Any]]:
        from thrustmap.flightlogs.telemetry import is_vehicle_heartbeat

        opened_us = self.clock_us()
        last_heard_us = opened_us
        while not self._stopped:
            msg = self.link.recv_match(blocking=True, timeout=self.poll_s)
            now_us = self.clock_us()
            if msg is None:
                silent_s = (now_us - last_heard_us) / 1e6
                if self._vehicle is None and silent_s > self.start_timeout_s:
                    raise LinkLost(f"no vehicle heard on {self.url} in {silent_s:.0f} s")
                if self._vehicle is not None and silent_s > self.link_timeout_s:
                    raise LinkLost(
                        f"no message from system {self._vehicle[0]} for {silent_s:.1f} s"
                    )
                continue
            if msg.get_type() == "BAD_DATA":
                self.bad_bytes += len(getattr(msg, "data", b""))
                continue
            if self.recorder is not None:
                self.recorder.write(now_us, bytes(msg.get_msgbuf()))
            if self._vehicle is None and is_vehicle_heartbeat(msg):
                self._vehicle = (msg.get_srcSystem(), msg.get_srcComponent(), int(msg.autopilot))
                self._request(int(msg.autopilot))
                self._asked_at_us = now_us
            if self._vehicle is not None and msg.get_srcSystem() == self._vehicle[0]:
                last_heard_us = now_us
                self._seen.add(msg.get_type())
                if msg.get_type() == "PARAM_VALUE":
                    pid = msg.param_id
                    name = pid.decode("ascii", "replace") if isinstance(pid, bytes) else str(pid)
                    self._param_names.add(name.rstrip("\x00"))
                if msg.get_type() == "COMMAND_ACK":
                    self._ack(msg)
            if (
                not self._retried
                and self._asked_at_us is not None
                and now_us - self._asked_at_us > RETRY_AFTER_S * 1e6
            ):
                self._retried = True  # once: a vehicle still booting may have missed the first
                self._request(self._vehicle[2] if self._vehicle else 0, only_missing=True)
            yield now_us * 1e-6, msg

    # -- requests (rates and parameter reads only) ---------------------------------------------
    def _request(self, autopilot: int, *, only_missing: bool = False) -> None:
        assert self._vehicle is not None
        system, component, _ = self._vehicle
        self._pending = {}
        for name, (msg_id, hz) in rates_for(autopilot).items():
            if only_missing and name in self._seen:
                continue
            self.requests.answers.pop(name, None)
            self.requests.asked[name] = hz
            self._pending[msg_id] = name
            self.link.mav.command_long_send(
                system,
                component,
                MAV_CMD_SET_MESSAGE_INTERVAL,
                0,
                float(msg_id),
                1e6 / hz,
                0,
                0,
                0,
                0,
                0,
            )
        self.requests.params = params_for(autopilot)
        for name in self.requests.params:
            if only_missing and name in self._param_names:
                continue
            self.link.mav.param_request_read_send(system, component, name.encode(), -1)
        log.info(
            "asked %s for %s (SET_MESSAGE_INTERVAL) and parameters %s",
            self.url,
            ", ".join(f"{k} {v:g} Hz" for k, v in self.requests.asked.items()),
            ", ".join(self.requests.params),
        )

    def _ack(self, msg: Any) -> None:
        if msg.command != MAV_CMD_SET_MESSAGE_INTERVAL:
            return
        pending = self._pending
        # acks come in the order of the requests (one outstanding COMMAND_LONG id for all)
        for msg_id, name in list(pending.items()):
            if name not in self.requests.answers:
                self.requests.answers[name] = MAV_RESULT_NAMES.get(
                    int(msg.result), f"result {msg.result}"
                )
                del pending[msg_id]
                break


class TlogReplay:
    """A .tlog as ``(time_s, message)`` pairs, at full speed (``replay://path.tlog``)."""

    def __init__(self, path: Path) -> None:
        from pymavlink import mavutil

        if not path.is_file():
            raise ConfigError("recording not found", file=str(path))
        if path.stat().st_size == 0:
            raise DataFormatError("recording is empty (0 bytes)", file=str(path))
        self.url = f"replay://{path}"
        self.path = path
        self.requests = RateRequests()
        self.bad_bytes = 0
        self._stopped = False
        self._log = mavutil.mavlink_connection(str(path), robust_parsing=True)

    def stop(self) -> None:
        self._stopped = True

    def close(self) -> None:
        self._log.close()

    def messages(self) -> Iterator[tuple[float, Any]]:
        while not self._stopped:
            try:
                m = self._log.recv_match(blocking=False)
            except Exception as exc:  # pymavlink raises assorted errors on garbage
                log.warning("%s: recording ends in unreadable data (%s)", self.path, exc)
                return
            if m is None:
                return
            if m.get_type() == "BAD_DATA":
                self.bad_bytes += len(getattr(m, "data", b""))
                continue
            yield float(m._timestamp), m


def open_stream(
    url: str,
    *,
    record: Path | None = None,
    link_timeout_s: float = 5.0,
    start_timeout_s: float = 30.0,
    signing_key: Any = None,
) -> LiveStream | TlogReplay:
    """``replay://path.tlog`` replays a recording; anything else is a live link."""
    if url.lower().startswith("replay://"):
        path = Path(url[len("replay://") :])
        if path.suffix.lower() != ".tlog":
            raise ConfigError(
                f"{url}: gamma live replays a .tlog (made with --record); got {path.suffix or 'no suffix'}"
            )
        if record is not None:
            raise ConfigError("--record with replay://: the recording already exists")
        return TlogReplay(path)
    return LiveStream(
        url,
        record=record,
        link_timeout_s=link_timeout_s,
        start_timeout_s=start_timeout_s,
        signing_key=signing_key,
    )
