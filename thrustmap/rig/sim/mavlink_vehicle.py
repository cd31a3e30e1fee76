"""The common part of the simulated MAVLink vehicles: a byte-level peer on pymavlink.

A vehicle is a ``thrustmap.protocols.peer.BytePeer``: the host's bytes go in through
``write(data, now_s)``, the vehicle's bytes come out of ``read(now_s)``. Every call first
brings the vehicle up to ``now_s`` (motor-test timeouts, then periodic messages), so time comes
only from the caller's clock. Framing and encoding are pymavlink's (``MavlinkCodec``).

This base class handles what both firmwares share: HEARTBEAT at 1 Hz, telemetry streams at
``telemetry_rate_hz`` (changed per message by MAV_CMD_SET_MESSAGE_INTERVAL), parameters
(PARAM_REQUEST_READ/LIST, PARAM_SET), AUTOPILOT_VERSION on MAV_CMD_REQUEST_MESSAGE and
COMMAND_ACK for every COMMAND_LONG. Subclasses say which autopilot they are, which streams they
send and how they answer commands.

Parameters travel as real firmware sends them: each has a MAV_PARAM_TYPE (``param_types``;
REAL32 unless a subclass says otherwise) and integers are encoded the firmware's way
(``param_encoding``: PX4 bytewise, ArduPilot C cast), announced by the AUTOPILOT_VERSION
capability bits. An unknown name is answered with PARAM_ERROR where the firmware does that
(``param_error_for_unknown``, PX4) and with silence otherwise (ArduPilot).

MAVLink 2 signing as the real firmware does it (ArduPilot's GCS_Signing.cpp): with a
``signing_key`` the vehicle signs everything it sends and silently ignores unsigned or wrongly
signed messages (``refused_messages``), except RADIO_STATUS/RADIO; ``accept_unsigned=True`` is
ArduPilot's first port (channel 0), which takes unsigned messages too while still signing its
own. SETUP_SIGNING sets the key where ``accepts_setup_signing`` (ArduPilot; all zeros turn
signing off). Signing timestamps are this computer's time (as the host's), not the simulated
clock: pymavlink refuses a stream more than a minute older than its own timestamp.
"""

from __future__ import annotations

import logging
import math
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from thrustmap.protocols.mavlink import codec as mav
from thrustmap.protocols.mavlink import encode as enc
from thrustmap.protocols.mavlink.params import (
    ParamEncoding,
    ParamType,
    decode_param,
    encode_param_float,
    float_field_bytes,
)
from thrustmap.protocols.mavlink.signing import SigningKey, sign_mavlink
from thrustmap.rig.sim.plant import Plant, PlantState

log = logging.getLogger(__name__)

HEARTBEAT_ID = 0
MAX_CATCH_UP = 100  # instances of one catch-up stream per read, at most
SIGNING_EPOCH_S = 1420070400  # MAVLink signing timestamps count from 2015-01-01 (10 µs units)


class SimMavlinkVehicle(ABC):
    """A MAVLink vehicle at the byte level; see the module docstring."""

    autopilot: int = 0
    param_encoding: ParamEncoding = ParamEncoding.C_CAST
    param_error_for_unknown = False
    #: AUTOPILOT_VERSION as the firmware sends it
    capabilities = 0
    flight_sw_version = 0

    def __init__(
        self,
        plant: Plant,
        *,
        system_id: int = 1,
        component_id: int = 1,
        telemetry_rate_hz: float = 10.0,
        params: Mapping[str, float] | None = None,
        signing_key: SigningKey | None = None,
        accept_unsigned: bool = False,
    ) -> None:
        self.plant = plant
        self.system_id = system_id
        self.component_id = component_id
        self._codec = mav.MavlinkCodec(system_id, component_id)
        self.accept_unsigned = accept_unsigned
        self.signing_key: SigningKey | None = None
        if signing_key is not None:
            self.set_signing_key(signing_key)
        self._frames: list[bytes] = []
        self._boot_s: float | None = None
        self._now_s = 0.0
        self.params: dict[str, float] = dict(self.default_params())
        self.params.update(params or {})
        self.param_types: dict[str, int] = dict(self.default_param_types())
        period_s = 1.0 / telemetry_rate_hz if telemetry_rate_hz > 0 else math.inf
        self._streams: dict[int, tuple[Callable[[PlantState], list[Any]], float]] = {
            HEARTBEAT_ID: (lambda state: [self._heartbeat()], 1.0),
        }
        for message_id, builder in self.telemetry_streams().items():
            self._streams[message_id] = (builder, period_s)
        self._default_periods = {k: v[1] for k, v in self._streams.items()}
        self._next_due: dict[int, float] = {}
        #: streams sent at their rate even when nobody reads (see ``_advance``)
        self.catch_up_streams: set[int] = set()
        self.commands_received: list[mav.CommandLong] = []

    # -- signing ---------------------------------------------------------------------------
    accepts_setup_signing = False

    def set_signing_key(self, key: SigningKey | None, timestamp: int | None = None) -> None:
        """Sign with ``key`` from now on (None: signing off)."""
        mav_obj = self._codec.mav
        self.signing_key = key
        if key is None:
            mav_obj.signing.secret_key = None
            mav_obj.signing.sign_outgoing = False
            mav_obj.signing.allow_unsigned_callback = None
            return
        if timestamp is None:
            timestamp = int(max(0.0, time.time() - SIGNING_EPOCH_S) * 100_000)
        sign_mavlink(mav_obj, key, timestamp=timestamp)
        if self.accept_unsigned:
            mav_obj.signing.allow_unsigned_callback = lambda _mav, _msg_id: True

    @property
    def refused_messages(self) -> int:
        """Messages ignored because they were unsigned or wrongly signed."""
        return int(self._codec.mav.signing.reject_count)

    def _setup_signing(self, msg: Any) -> None:
        if not self.accepts_setup_signing or self.armed:
            return
        if int(msg.target_system) not in (0, self.system_id):
            return
        secret = bytes(msg.secret_key)
        if not any(secret) and int(msg.initial_timestamp) == 0:
            self.set_signing_key(None)
        else:
            self.set_signing_key(SigningKey(secret), int(msg.initial_timestamp) + 6_000_000)

    # -- what subclasses provide ----------------------------------------------------------
    def default_params(self) -> Mapping[str, float]:
        return {}

    def default_param_types(self) -> Mapping[str, int]:
        """MAV_PARAM_TYPE per name (REAL32 when absent)."""
        return {}

    @abstractmethod
    def telemetry_streams(self) -> Mapping[int, Callable[[PlantState], list[Any]]]:
        """message id -> function building that message (or messages) from the plant state."""

    @property
    @abstractmethod
    def armed(self) -> bool:
        """What HEARTBEAT reports (base_mode & 128)."""

    @abstractmethod
    def handle_command(self, command: mav.CommandLong, now_s: float) -> int:
        """Act on a COMMAND_LONG; return the MAV_RESULT to acknowledge it with."""

    def update(self, now_s: float) -> None:  # noqa: B027 - optional hook
        """Advance internal timers (motor-test timeouts) to ``now_s``."""

    # -- BytePeer ---------------------------------------------------------------------------
    def write(self, data: bytes, now_s: float) -> None:
        self._advance(now_s)
        for msg in self._codec.feed(data):
            self._dispatch(msg, now_s)

    def read(self, now_s: float) -> bytes:
        return b"".join(self.read_frames(now_s))

    def read_frames(self, now_s: float) -> list[bytes]:
        """Like ``read`` but one ``bytes`` per MAVLink frame (a datagram each over UDP)."""
        self._advance(now_s)
        frames, self._frames = self._frames, []
        return frames

    # -- helpers for subclasses ------------------------------------------------------------
    @property
    def time_since_boot_s(self) -> float:
        return 0.0 if self._boot_s is None else self._now_s - self._boot_s

    def set_plant_throttle(self, motor: int, fraction: float, time_s: float) -> None:
        """Drive the plant at ``time_s``; a moment the plant has already passed (a stand that
        shares it read it later, e.g. a motor-test timeout found late) is applied now."""
        try:
            self.plant.set_throttle(motor, fraction, time_s)
        except ValueError:
            self.plant.set_throttle(motor, fraction, self._now_s)

    def send(self, msg: Any) -> None:
        self._frames.append(self._codec.encode(msg))

    def state(self) -> PlantState:
        return self.plant.state(self._now_s)

    def _heartbeat(self) -> Any:
        return enc.heartbeat_message(self.autopilot, armed=self.armed)

    # -- internals ---------------------------------------------------------------------------
    def _advance(self, now_s: float) -> None:
        if self._boot_s is None:
            self._boot_s = now_s
            self._next_due = {k: now_s for k in self._streams}
        now_s = max(now_s, self._now_s)
        self._now_s = now_s
        self.update(now_s)
        due = [k for k, t in self._next_due.items() if t <= now_s]
        if not due:
            return
        state = self.plant.state(now_s)
        for message_id in due:
            builder, period_s = self._streams[message_id]
            if message_id in self.catch_up_streams:
                # Sent at its own rate whether or not anyone reads: a slow reader finds every
                # missed instance waiting (as in a serial or socket buffer), up to a bound.
                missed = int((now_s - self._next_due[message_id]) / period_s) + 1
                for _ in range(min(missed, MAX_CATCH_UP)):
                    for msg in builder(state):
                        self.send(msg)
                self._next_due[message_id] += missed * period_s
                continue
            for msg in builder(state):
                self.send(msg)
            nxt = self._next_due[message_id] + period_s
            # After a long gap, resume the schedule from now instead of sending a burst.
            self._next_due[message_id] = nxt if nxt > now_s else now_s + period_s

    def _dispatch(self, msg: Any, now_s: float) -> None:
        kind = msg.get_type()
        if kind == "COMMAND_LONG":
            command = mav.CommandLong.from_message(msg)
            if command.target_system not in (0, self.system_id):
                return
            self.commands_received.append(command)
            if command.command == mav.MAV_CMD_SET_MESSAGE_INTERVAL:
                result = self._set_message_interval(command)
            elif command.command == mav.MAV_CMD_REQUEST_MESSAGE:
                result = self._request_message(command)
            else:
                result = self.handle_command(command, now_s)
            self.send(
                enc.command_ack_message(
                    command.command,
                    result,
                    target_system=msg.get_srcSystem(),
                    target_component=msg.get_srcComponent(),
                )
            )
        elif kind == "SETUP_SIGNING":
            self._setup_signing(msg)
        elif kind == "PARAM_REQUEST_READ":
            self._send_param(mav.decode_text(msg.param_id), int(msg.param_index))
        elif kind == "PARAM_REQUEST_LIST":
            for index in range(len(self.params)):
                self._send_param("", index)
        elif kind == "PARAM_SET":
            name = mav.decode_text(msg.param_id)
            if name in self.params:
                ptype = self.param_types.get(name, ParamType.REAL32)
                value = decode_param(
                    float_field_bytes(float(msg.param_value)), ptype, self.param_encoding
                )
                self.params[name] = value
                self.on_param_set(name, value)
                self._send_param(name, -1)
            elif self.param_error_for_unknown:
                self._send_param_error(name)

    def on_param_set(self, name: str, value: float) -> None:  # noqa: B027 - optional hook
        """React to a PARAM_SET (after ``params`` is updated)."""

    def _send_param(self, name: str, index: int) -> None:
        names = sorted(self.params)
        if name:
            if name not in self.params:
                if self.param_error_for_unknown:
                    self._send_param_error(name)
                return  # ArduPilot stays silent about unknown names
            index = names.index(name)
        elif not 0 <= index < len(names):
            return
        key = names[index]
        ptype = self.param_types.get(key, ParamType.REAL32)
        wire = encode_param_float(self.params[key], ptype, self.param_encoding)
        self.send(enc.param_value_message(key, wire, index, len(names), param_type=ptype))

    def _send_param_error(self, name: str) -> None:
        self.send(
            mavlink2.MAVLink_param_error_message(
                255,
                190,
                name.encode("ascii")[:16],
                -1,
                1,  # MAV_PARAM_ERROR_DOES_NOT_EXIST
            )
        )

    def _request_message(self, command: mav.CommandLong) -> int:
        if int(command.params[0]) != mav.MSG_AUTOPILOT_VERSION:
            return mav.MavResult.DENIED
        self.send(
            mavlink2.MAVLink_autopilot_version_message(
                self.capabilities,
                self.flight_sw_version,
                0,
                0,
                0,
                [0] * 8,
                [0] * 8,
                [0] * 8,
                0,
                0,
                0,
                [0] * 18,
            )
        )
        return mav.MavResult.ACCEPTED

    def _set_message_interval(self, command: mav.CommandLong) -> int:
        message_id = int(command.params[0])
        interval_us = command.params[1]
        if message_id not in self._streams:
            return mav.MavResult.DENIED
        builder, _ = self._streams[message_id]
        if interval_us < 0:
            period_s = math.inf
        elif interval_us == 0:
            period_s = self._default_periods[message_id]
        else:
            period_s = interval_us / 1e6
        self._streams[message_id] = (builder, period_s)
        self._next_due[message_id] = self._now_s + (0.0 if math.isfinite(period_s) else math.inf)
        return mav.MavResult.ACCEPTED
