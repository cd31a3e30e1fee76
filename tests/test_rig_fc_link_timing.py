"""MSP and MAVLink timing from the link itself (issue 20): reply waits learned from the round
trip, replies matched to their request by command, stale ones dropped, a fast stop whatever
the latency, and no stop (and no alarm) from a session that commanded nothing. On a simulated
clock: exact."""

from __future__ import annotations

import logging

import pytest
from support.latency_proxy import LaggedPeer

import thrustmap.rig.devices.urls as urls
from thrustmap.core.clock import SimClock
from thrustmap.protocols.msp.framing import MspCommand, MspDecoder, encode_reply
from thrustmap.protocols.msp.motor import MSP_MOTOR_STOP, SetMotor
from thrustmap.protocols.peer import BytePeer, create_peer
from thrustmap.protocols.urlhandlers.protocol_sim import SimSerial
from thrustmap.rig.fc.link_timing import ReplyTimer
from thrustmap.rig.fc.msp import MspThrottleOutput, MspTimeout
from thrustmap.rig.sim import peers

urls.load_sim_peers()

STOP_PAYLOAD = SetMotor.stop_all(8).encode()


class Wire:
    """Between the driver and the (lagged) FC: logs host writes by simulated time, and can
    drop host frames (a cable that loses them) or cut the link."""

    def __init__(self, inner: BytePeer, clock: SimClock) -> None:
        self.inner = inner
        self.clock = clock
        self.writes: list[tuple[float, int, bytes]] = []  # (time, cmd, payload)
        self.drop: list[bytes] = []  # payload prefixes... exact frames to lose once each
        self.dead = False
        self.front: bytes = b""  # bytes delivered before anything else (an old connection's)

    def write(self, data: bytes, now_s: float) -> None:
        for frame in MspDecoder().feed(data):
            self.writes.append((now_s, frame.cmd, frame.payload))
        if self.dead:
            return
        if data in self.drop:
            self.drop.remove(data)
            return
        self.inner.write(data, now_s)

    def read(self, now_s: float) -> bytes:
        out = self.front + self.inner.read(now_s)
        self.front = b""
        return b"" if self.dead else out

    def stops(self, after_s: float = 0.0) -> list[float]:
        return [
            t
            for t, cmd, p in self.writes
            if cmd == MspCommand.SET_MOTOR and p == STOP_PAYLOAD and t >= after_s
        ]


def fc(
    delay_s: float, clock: SimClock | None = None, **opts: object
) -> tuple[MspThrottleOutput, Wire, LaggedPeer, SimClock]:
    clock = clock or SimClock(100.0)
    peers.reset_benches()
    peer = create_peer(
        "betaflight", {"bench": "timing", "protocol": "PWM", "firmware": "betaflight-4"}
    )
    lagged = LaggedPeer(peer, delay_s)
    wire = Wire(lagged, clock)  # type: ignore[arg-type]
    port = SimSerial(wire, clock, timeout=0)
    return MspThrottleOutput(port, clock, **opts), wire, lagged, clock  # type: ignore[arg-type]


# --------------------------------------------------------------------------- the timer


def test_reply_timer_follows_the_round_trip_within_bounds() -> None:
    timer = ReplyTimer(initial_s=0.5, min_s=0.05, max_s=1.5)
    assert timer.timeout_s == 0.5  # nothing measured yet
    timer.sample(0.010)
    assert timer.timeout_s == pytest.approx(0.05)  # 10 ms + 4 x 5 ms, raised to the floor
    for _ in range(20):
        timer.sample(0.400)
    assert 0.4 < timer.timeout_s < 0.6
    timer.sample(0.680)  # a spike widens the deviation, so the next wait covers it
    assert timer.timeout_s > 0.6
    for _ in range(5):
        timer.sample(5.0)
    assert timer.timeout_s == 1.5  # bounded
    assert timer.timeout_for_try(1) == 1.5 and timer.timeout_for_try(3) == 1.5
    slow = ReplyTimer()
    slow.sample(0.1)
    assert slow.timeout_for_try(2) == pytest.approx(2 * slow.timeout_s)  # doubled per retry


# --------------------------------------------------------------------------- slow links


@pytest.mark.parametrize("delay_s", [0.0, 0.05, 0.2, 0.5])
def test_identify_and_a_verified_stop_over_a_slow_link(delay_s: float) -> None:
    output, wire, _, clock = fc(delay_s)
    identity = output.identify()
    assert identity.kind == "betaflight"
    assert output.timer.srtt_s is not None and output.timer.srtt_s >= delay_s
    output.set_throttle({0: 1400.0})
    assert output.motor_values()[0] == 1400
    asked_at = clock.now_s()
    assert output.stop_and_verify() is True
    # the stop went out at once, and was verified about one round trip later (when the
    # driver turns to re-enabling arming)
    assert wire.stops(asked_at)[0] == asked_at
    verified_at = next(
        t for t, cmd, p in wire.writes if cmd == MspCommand.SET_ARMING_DISABLED and p == b"\x00"
    )
    assert verified_at - asked_at <= delay_s + 0.05
    assert output.motor_values()[:4] == (MSP_MOTOR_STOP,) * 4
    output.close()


def test_the_old_fixed_100ms_wait_fails_where_the_adaptive_one_does_not() -> None:
    fixed, _, _, _ = fc(0.5, timeout_s=0.1, retries=2)
    with pytest.raises(MspTimeout, match="command 1 after 3 tries over 300 ms"):
        fixed.identify()
    adaptive, _, _, _ = fc(0.5)
    assert adaptive.identify().firmware_version


def test_a_spike_is_waited_out_and_its_late_copies_are_dropped_as_stale(
    caplog: pytest.LogCaptureFixture,
) -> None:
    output, wire, lagged, clock = fc(0.02)
    output.identify()
    output.set_throttle({0: 1500.0})
    for _ in range(10):
        output.read_telemetry()  # the timer learns a ~20 ms link
    lagged.delay_s = 0.7  # one reply takes 0.7 s (a busy SITL): several tries go out
    t0 = clock.now_s()
    assert output.motor_values()[0] == 1500
    motor_reads = [t for t, cmd, _ in wire.writes if cmd == MspCommand.MOTOR and t >= t0]
    assert len(motor_reads) >= 3  # retried before the reply came...
    assert clock.now_s() - t0 == pytest.approx(0.7, abs=0.05)  # ...and took the first answer
    lagged.delay_s = 0.02
    with caplog.at_level(logging.DEBUG, logger="thrustmap.rig.fc.msp"):
        assert output.stop_and_verify() is True
        # the copies' late answers (motor 1 at 1500) did not pass for the verifying read
        assert output.stale_replies >= len(motor_reads) - 1
    assert any("stale reply to cmd 104" in r.getMessage() for r in caplog.records)
    output.close()


def test_replies_left_from_an_earlier_connection_are_dropped() -> None:
    output, wire, _, _ = fc(0.05)
    stale = encode_reply(MspCommand.SET_MOTOR) * 2  # what a SITL delivered after a reconnect
    wire.front = stale
    running = encode_reply(MspCommand.MOTOR, bytes.fromhex("dc05") + bytes.fromhex("e803") * 7)
    wire.front += running  # and an old MSP_MOTOR showing motor 1 at 1500
    output.identify()
    assert output.stale_replies == 3
    output.set_throttle({0: 1200.0})
    assert output.stop_and_verify() is True


def test_a_lost_stop_frame_costs_the_resend_cadence_not_a_reply_timeout() -> None:
    output, wire, _, clock = fc(0.5)
    output.identify()
    output.set_throttle({0: 1500.0})
    from thrustmap.protocols.msp.framing import encode_request

    wire.drop.append(encode_request(MspCommand.SET_MOTOR, STOP_PAYLOAD))
    t0 = clock.now_s()
    assert output.stop_and_verify() is True
    stops = wire.stops(t0)
    assert stops[0] == t0 and stops[1] - t0 == pytest.approx(0.1, abs=0.005)
    verified_at = next(
        t for t, cmd, _ in wire.writes if cmd == MspCommand.SET_ARMING_DISABLED and t > t0
    )
    assert verified_at - t0 < 1.15  # two round trips at most, whatever the reply timeout


# --------------------------------------------------------------------------- nothing commanded


def test_a_session_that_commanded_nothing_sends_no_stop_and_raises_no_alarm(
    caplog: pytest.LogCaptureFixture,
) -> None:
    output, wire, _, _ = fc(0.3)
    output.identify()
    output.read_telemetry()
    output.motor_values()
    wire.dead = True  # the link goes quiet at the end of a probe
    with caplog.at_level(logging.INFO):
        assert output.stop_and_verify() is True
    assert wire.stops() == []
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR]
    assert "no stop to send" in caplog.text


def test_a_commanded_motor_on_a_dead_link_is_a_real_alarm(caplog: pytest.LogCaptureFixture) -> None:
    output, wire, _, _ = fc(0.05)
    output.identify()
    output.set_throttle({0: 1500.0})
    wire.dead = True
    with caplog.at_level(logging.WARNING):
        assert output.stop_and_verify() is False
    assert "COULD NOT VERIFY MOTOR STOP" in caplog.text
    assert len(wire.stops()) >= 3  # it kept stopping while it waited


# --------------------------------------------------------------------------- MAVLink command acks


def _px4(delay_s: float, **opts: object) -> tuple[object, SimClock]:
    from thrustmap.protocols.mavlink.link import MavlinkSerialLink
    from thrustmap.rig.fc.mavlink import open_mavlink_output

    peers.reset_benches()
    clock = SimClock(100.0)
    peer = create_peer("px4", {"bench": "timing", "motors": "1"})
    port = SimSerial(LaggedPeer(peer, delay_s), clock, timeout=0)
    return open_mavlink_output(MavlinkSerialLink(port, clock), clock, **opts), clock  # type: ignore[arg-type]


def test_mavlink_ack_wait_is_learned_from_the_link() -> None:
    from thrustmap.protocols.mavlink import codec as mav

    out, clock = _px4(1.2)  # a radio link: 1.2 s per reply, longer than the old 2 x 0.5 s
    session = out.session  # type: ignore[attr-defined]
    for _ in range(3):  # every command answered; the wait backs off until it is measured
        assert session.command(mav.request_message(mav.MSG_AUTOPILOT_VERSION)).accepted
    assert session.ack_timer.srtt_s == pytest.approx(1.2, abs=0.1)
    assert session.ack_timeout_s == 1.5  # learned: the round trip is long, the wait bounded
    t0 = clock.now_s()
    assert session.command(mav.request_message(mav.MSG_AUTOPILOT_VERSION)).accepted
    assert clock.now_s() - t0 == pytest.approx(1.2, abs=0.1)
    fixed, _ = _px4(1.2, ack_timeout_s=0.5)
    from thrustmap.rig.fc.mavlink_session import MavlinkLinkLost

    with pytest.raises(MavlinkLinkLost, match="after 2 tries"):
        fixed.session.command(mav.request_message(mav.MSG_AUTOPILOT_VERSION))  # type: ignore[attr-defined]


@pytest.mark.parametrize("delay_s", [0.05, 0.5])
def test_mavlink_stop_verified_over_a_slow_link(delay_s: float) -> None:
    out, clock = _px4(delay_s)
    out.identify()  # type: ignore[attr-defined]
    out.set_throttle({0: float(out.throttle_scale.from_pct(10.0))})  # type: ignore[attr-defined]
    clock.sleep_s(1.0)
    out.keepalive()  # type: ignore[attr-defined]
    assert out.stop_and_verify() is True  # type: ignore[attr-defined]


class OneByteReads:
    """A port like pyserial's ``socket://``: ``in_waiting`` says 0, a read gives one byte."""

    def __init__(self, inner: SimSerial) -> None:
        self.inner = inner

    timeout = 0.0
    in_waiting = 0

    def read(self, size: int = 1) -> bytes:
        return self.inner.read(1)

    def write(self, data: bytes) -> int | None:
        return self.inner.write(data)

    def close(self) -> None:
        self.inner.close()


def test_telemetry_kept_on_the_wire_through_a_port_that_reads_a_byte_at_a_time() -> None:
    output, _, _, clock = fc(0.05)
    output.port = OneByteReads(output.port)  # type: ignore[arg-type, assignment]
    output.identify()
    first = output.read_telemetry()
    times = []
    for _ in range(20):
        clock.sleep_s(0.1)
        times.append(output.read_telemetry().time_s)  # never blocks on the link
    assert times[-1] - first.time_s > 1.5  # fresh replies kept coming in
    assert times[-1] >= clock.now_s() - 0.2
